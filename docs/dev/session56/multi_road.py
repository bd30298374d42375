"""Session 56 (issue 16), development data only: are road readings over longer baselines (frame k-j to k,
j = 1..3) less noisy and less biased than the one-step readings the shipped smoother uses?

For each development sequence: leovr's camera-only motion alone (as `tools/step_length_dev.py`), cached in
runs/s56/motion_<name>.pkl; then for each frame k and span j the road corners of frame k-j tracked (chained LK)
to frame k, triangulated with the motion's unit-length composite step k-j -> k, and the road's height read as
the product does (`fit_ground`). Prints per span: readings, mean / std of log(reading / reference length) and the
slope of that error against log reference length (the speed-dependent bias).

    .venv/bin/python docs/dev/session56/multi_road.py [--sampson PX] -- SEQ ...
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from step_length_dev import chain, dev_runs, motion_steps  # noqa: E402

from leovr.geometry import invert_T  # noqa: E402
from leovr.pipeline.refine import road_height  # noqa: E402
from odometry.ground_plane import fit_ground, road_corners  # noqa: E402
from odometry.mono_motion import rotation_parallax, sampson_px, triangulate  # noqa: E402
from odometry.mono_vo import follow, gray  # noqa: E402

CACHE = Path("runs/s56")


def cached_motion(path, seq, cfg, gen):
    CACHE.mkdir(parents=True, exist_ok=True)
    f = CACHE / f"motion_{Path(path).name}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    out = motion_steps(seq, cfg, gen)
    f.write_bytes(pickle.dumps(out))
    return out


def span_reading(grays, k, j, T_unit, K, cam_h, sampson=None, min_par=1.0):
    """log metric length of the composite step k-j -> k from the road, and the plane's inliers (None if no fit)."""
    p0 = road_corners(grays[k - j], K, cam_h)
    if len(p0) < 8:
        return None
    p, ok = p0, np.ones(len(p0), bool)
    for i in range(k - j, k):
        p, o = follow(grays[i], grays[i + 1], p)
        ok &= o
    p0, p1 = p0[ok], p[ok]
    if sampson is not None:
        keep = sampson_px(T_unit, p0, p1, K) < sampson
        p0, p1 = p0[keep], p1[keep]
    if len(p0) < 8:
        return None
    X = triangulate(T_unit, p0, p1, K)
    par = rotation_parallax(p0, p1, T_unit[:3, :3].T, K)
    fit = fit_ground(X[par > min_par])
    if fit is None:
        return None
    return float(np.log(cam_h / fit.height)), fit.inliers


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--spans", nargs="*", type=int, default=[1, 2, 3])
    ap.add_argument("--sampson", type=float, default=None)
    a = ap.parse_args()
    for path, seq, ref, ref_name, cfg, gen in dev_runs(a.sequences):
        steps, readings = cached_motion(path, seq, cfg, gen)
        P = chain(steps)
        n = len(P)
        K = seq[0].K
        cam_h = road_height(seq, cfg) or 1.65
        grays = [gray(seq[i].image) for i in range(n)]
        row = {"sequence": Path(path).name}
        for j in a.spans:
            err, lref = [], []
            for k in range(j, n):
                T = invert_T(P[k - j]) @ P[k]
                L = np.linalg.norm(T[:3, 3])
                Lr = np.linalg.norm((invert_T(ref[k - j]) @ ref[k])[:3, 3])
                if L < 1e-6 or Lr < 0.02:
                    continue
                Tu = T.copy()
                Tu[:3, 3] /= L
                r = span_reading(grays, k, j, Tu, K, cam_h, a.sampson)
                if r is None:
                    continue
                err.append(r[0] - np.log(Lr))
                lref.append(np.log(Lr))
            err, lref = np.array(err), np.array(lref)
            slope = float(np.polyfit(lref, err, 1)[0]) if len(err) > 3 and np.ptp(lref) > 0.05 else float("nan")
            mad = 1.4826 * np.median(np.abs(err - np.median(err))) if len(err) else float("nan")
            row[f"j{j}"] = dict(n=len(err), mean=round(float(err.mean()), 4), std=round(float(err.std()), 4),
                                mad=round(float(mad), 4), slope=round(slope, 3))
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
