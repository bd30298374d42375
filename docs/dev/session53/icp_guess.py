"""Session 53 development check (issue 16, loop laps): KISS-ICP predicted with the images' motion
(`refine.icp_guess: images`) against its constant velocity, on the *tuning* laps only (seeds 3000/3001 by default;
the loop benchmark's reported seeds are refused). Each lap is rendered as `leovr bench loop` renders it (kept in DIR
and reused), refined with loop closure under each setting, and reported: ATE before / after loop closure, KISS-ICP's
own ATE, loops true / false, and the worst per-step rotation error in turns (true rotation > 2 degrees) of
KISS-ICP's poses and of leovr's poses before loop closure.

    .venv/bin/python docs/dev/session53/icp_guess.py DIR [--lidars vlp16] [--seeds 3000 3001]
        [--cfg '{"icp_guess": "images"}' --tag images]

With `--val`: the validation split's drives of the first of `--lidars` instead (seeds 2000-2002: city loop, straight, dynamic; day and
night; 40 frames at 448 x 256, rendered into DIR as the dataset recipe renders them), refined as `leovr bench
refine` refines its drives (no loop closure), ATE of leovr and of KISS-ICP alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from leovr.bench.loop import loop_truth  # noqa: E402
from leovr.config import BenchLoopConfig, RefineConfig, SimulateConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T, rotation_angle_deg  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402
from leovr.sim.dataset import RECIPES  # noqa: E402
from leovr.sim.simulate import simulate  # noqa: E402


def turn_errors(P: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """Worst and median per-step rotation error (degrees) over the turning steps."""
    err, turn = [], []
    for k in range(1, len(P)):
        g = invert_T(gt[k - 1]) @ gt[k]
        e = invert_T(P[k - 1]) @ P[k]
        err.append(rotation_angle_deg(g[:3, :3].T @ e[:3, :3]))
        turn.append(rotation_angle_deg(g[:3, :3]) > 2.0)
    err, turn = np.array(err), np.array(turn)
    return round(float(err[turn].max()), 2), round(float(np.median(err[turn])), 3)


def validation(keep: Path, overrides: dict, tag: str, lidar: str = "vlp16", lights: tuple[str, ...] = ("day", "night")) -> None:
    """The validation split's drives of one LiDAR, refined as `bench refine` does: ATE of leovr and KISS-ICP."""
    for split, sim in RECIPES["default"].items():
        if split != "val" or sim.lidar != lidar or sim.light not in lights:
            continue
        name = f"val_{sim.scenario}_{sim.lidar}_{sim.light}_s{sim.seed}"
        seq_dir = keep / name
        if not (seq_dir / "sequence.yaml").exists():
            simulate(sim, seq_dir, progress=False)
        m = run_refine(open_sequence(seq_dir), RefineConfig(window=4, compare=True, **overrides),
                       keep / f"run_{tag}_{name}", progress=False)
        t = m["trajectory"]
        print(json.dumps({"tag": tag, "drive": name, "ate": round(t["leovr"]["ate_m"], 4),
                          "ate_kiss_icp": round(t["kiss_icp"]["ate_m"], 4),
                          "refined_mae": round(m["depth"]["refined"]["mae_m"], 4) if "refined" in m.get("depth", {}) else None}), flush=True)


def main() -> None:
    bench = BenchLoopConfig()
    ap = argparse.ArgumentParser()
    ap.add_argument("keep")
    ap.add_argument("--lidars", nargs="*", default=["vlp16"])
    ap.add_argument("--seeds", type=int, nargs="*", default=bench.tuning_seeds)
    ap.add_argument("--cfg", default="{}", help="RefineConfig overrides as JSON")
    ap.add_argument("--tag", default="base")
    ap.add_argument("--val", action="store_true", help="the validation split's drives instead of the laps")
    ap.add_argument("--lights", nargs="*", default=["day", "night"], help="with --val")
    a = ap.parse_args()
    if a.val:
        return validation(Path(a.keep), json.loads(a.cfg), a.tag, a.lidars[0], tuple(a.lights))
    if set(a.seeds) & set(bench.seeds):
        raise SystemExit("the loop benchmark's reported seeds are not for development")
    keep = Path(a.keep)
    for lidar in a.lidars:
        for seed in a.seeds:
            seq_dir, run = keep / f"seq_{lidar}_{seed}", keep / f"run_{a.tag}_{lidar}_{seed}"
            if not (seq_dir / "sequence.yaml").exists():
                simulate(SimulateConfig(scenario="city_loop", lidar=lidar, frames=bench.frames, seed=seed,
                                        speed_kmh=bench.speed_kmh), seq_dir, progress=False)
            seq = open_sequence(seq_dir)
            cfg = RefineConfig(input="full", loop_closure=True, loop_min_gap=bench.loop_min_gap, **json.loads(a.cfg))
            m = run_refine(seq, cfg, run, progress=False)
            gt_list = [seq[i].T_world_cam for i in range(m["frames"])]
            loops = loop_truth(run, gt_list, cfg.loop_min_gap)
            state = json.loads((run / "progress.json").read_text())
            idx = sorted(int(k) for k in state["poses_no_loop"])
            get = lambda name: np.stack([np.array(state[name][str(i)]).reshape(4, 4) for i in idx])  # noqa: E731
            gt = np.stack([gt_list[i] for i in idx])
            t = m["trajectory"]
            out = {"tag": a.tag, "lap": f"{lidar}_s{seed}", "ate_no_loop": round(t["leovr_no_loop"]["ate_m"], 3),
                   "ate_loop": round(t["leovr"]["ate_m"], 3), "ate_kiss_icp": round(t["kiss_icp"]["ate_m"], 3),
                   "loops_true": loops["loops_true"], "loops_false": loops["loops_false"],
                   "turn_err_no_loop_max_median": turn_errors(get("poses_no_loop"), gt)}
            if all(str(i) in state.get("icp_poses", {}) for i in idx):
                out["turn_err_icp_max_median"] = turn_errors(get("icp_poses"), gt)
            print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
