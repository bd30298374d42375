"""Session 52 development check: the dense road homography reading (`odometry/road_homography.py`) against
the road corners' triangulated reading, per step, on the development clips (reference: the simulator's truth,
KISS-ICP on the full scan for the KITTI raw clip).

    .venv/bin/python docs/dev/session52/road_dense.py [--init filter|corners|one] [--corridor M] -- SEQ ...
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "tools"))
sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(Path(__file__).parent))

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from leovr.pipeline.completion import EvalSample  # noqa: E402
from leovr.pipeline.refine import road_height  # noqa: E402
from odometry.ground_plane import _corridor_mask  # noqa: E402
from odometry.mono_motion import MonoMotion  # noqa: E402
from odometry.step_length import LengthReading, rescale_steps, smooth_log_lengths  # noqa: E402
from road_homography import align_road  # noqa: E402
from step_length_dev import chain, dev_runs  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--init", default="filter", choices=["filter", "one", "half", "double"])
    ap.add_argument("--corridor", type=float, default=2.5)
    ap.add_argument("--margin", type=float, default=0.08)
    ap.add_argument("--sigma-floor", type=float, default=0.02)
    a = ap.parse_args()
    for path, seq, ref, ref_name, cfg, gen in dev_runs(a.sequences):
        n = len(seq)
        h = road_height(seq, cfg) or 1.65
        K = seq[0].K
        mm = MonoMotion(K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                        camera_height=h, ground_sigma_log=cfg.mono_ground_sigma_log)
        steps, readings, dense, rows = [], [], [], []
        t_dense = 0.0
        for i in range(n):
            f = seq[i]
            d, ls = gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
            prev = mm.prev_gray
            s = mm.step(f.image, d, ls)
            if s is None:
                continue
            cur = mm.prev_gray
            steps.append(s.T_rel)
            readings.append(s.length_reading)
            ref_len = float(np.linalg.norm((invert_T(ref[i - 1]) @ ref[i])[:3, 3]))
            L = float(np.linalg.norm(s.T_rel[:3, 3]))
            rd = None
            if s.scale_source != "standing" and L > 0:
                init = {"filter": L, "one": 1.0, "half": 0.5 * L, "double": 2.0 * L}[a.init]
                mask = _corridor_mask(cur.shape, tuple(np.asarray(K, float).ravel()), h, a.corridor, a.margin)
                t0 = time.perf_counter()
                rd = align_road(prev, cur, K, s.T_rel, h, init, mask)
                t_dense += time.perf_counter() - t0
            dense.append(None if rd is None else LengthReading(rd.log_length, max(rd.sigma_log, a.sigma_floor),
                                                               restart=bool(s.length_reading and s.length_reading.restart)))
            tri = s.length_reading.log_length if s.length_reading is not None else None
            rows.append((np.log(max(ref_len, 1e-6)), tri if tri is not None else np.nan,
                         rd.log_length if rd is not None else np.nan, rd.sigma_log if rd else np.nan))
        R = np.array(rows)
        out = {"sequence": Path(path).name, "reference": ref_name, "ms_dense": round(1000 * t_dense / max(len(R), 1), 1)}
        for j, name in ((1, "corners"), (2, "dense")):
            e = R[:, j] - R[:, 0]
            ok = np.isfinite(e) & (R[:, 0] > np.log(0.02))
            out[f"{name}_n"] = int(ok.sum())
            out[f"{name}_bias"] = round(float(np.mean(e[ok])), 4) if ok.any() else None
            out[f"{name}_std"] = round(float(np.std(e[ok])), 4) if ok.any() else None
            if ok.sum() > 3:
                out[f"{name}_slope"] = round(float(np.polyfit(R[ok, 0], e[ok], 1)[0]), 3)
        out["dense_sigma_med"] = round(float(np.nanmedian(R[:, 3])), 4)
        poses = chain(steps)
        out["filtered"] = poses
        out["smooth_corners"] = rescale_steps(poses, np.exp(smooth_log_lengths(readings, 0.005)))
        both = [rd if rd is not None else c for rd, c in zip(dense, readings)]
        out["smooth_dense"] = rescale_steps(poses, np.exp(smooth_log_lengths(both, 0.005)))
        dl = np.array([r.log_length if r is not None else np.nan for r in both], float)
        if np.isfinite(dl).all():
            out["raw_dense"] = rescale_steps(poses, np.exp(dl))
        out["true_len"] = rescale_steps(poses, np.exp(R[:, 0]))
        print(json.dumps({k: (round(trajectory_metrics(v, ref, "sim3")["ate_m"], 4) if isinstance(v, np.ndarray) else v)
                          for k, v in out.items()}), flush=True)


if __name__ == "__main__":
    main()
