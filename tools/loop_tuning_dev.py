#!/usr/bin/env python3
"""Development data for the loop validation's thresholds (issue 16), on the *tuning* laps only (seeds
3000 and 3001 by default; the reported seeds of `leovr bench loop` are never read): the laps are rendered
and refined with loop closure exactly as the benchmark does, and every candidate that reached the
geometric check is written with its statistics (inliers, reprojection error, forward / reverse PnP
disagreement, accepted or not) and how far its measured relative pose is from the truth.

    .venv/bin/python tools/loop_tuning_dev.py [--seeds 3000 3001] [--lidars mid40 vlp16] [--out runs/loop_tuning.jsonl]
        [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from leovr.bench.loop import loop_error
from leovr.config import BenchLoopConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.pipeline.refine import run_refine
from leovr.sim.simulate import simulate


def main() -> None:
    cfg = BenchLoopConfig()
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="*", default=cfg.tuning_seeds)
    ap.add_argument("--lidars", nargs="*", default=cfg.lidars)
    ap.add_argument("--out", default="runs/loop_tuning.jsonl")
    ap.add_argument("--keep", default=None, help="keep the rendered laps and their runs in this folder "
                    "(seq_LIDAR_SEED, run_LIDAR_SEED), e.g. for tools/pose_graph_dev.py")
    a = ap.parse_args()
    if set(a.seeds) & set(cfg.seeds):
        raise SystemExit(f"seeds {sorted(set(a.seeds) & set(cfg.seeds))} are the benchmark's reported ones: not for tuning")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch, open(a.out, "a") as fh:
        tmp = a.keep or scratch
        for lidar in a.lidars:
            for seed in a.seeds:
                seq_dir, run = Path(tmp) / f"seq_{lidar}_{seed}", Path(tmp) / f"run_{lidar}_{seed}"
                if (run / "loops.json").exists():  # kept from an earlier call
                    print(lidar, seed, "kept", flush=True)
                    continue
                simulate(SimulateConfig(scenario="city_loop", lidar=lidar, frames=cfg.frames, seed=seed,
                                        speed_kmh=cfg.speed_kmh), seq_dir, progress=False)
                seq = open_sequence(seq_dir)
                run_refine(seq, RefineConfig(input="full", loop_closure=True, loop_min_gap=cfg.loop_min_gap), run, progress=False)
                for r in json.loads((run / "loops.json").read_text())["loops"]:
                    T_j_i = r.pop("T_j_i")
                    if T_j_i is not None:
                        r["error_m"], r["error_deg"], r["true"] = loop_error(
                            np.array(T_j_i), seq[r["frame"]].T_world_cam, seq[r["candidate"]].T_world_cam)
                    fh.write(json.dumps({"lap": f"{lidar}_s{seed}", **r}) + "\n")
                fh.flush()
                print(lidar, seed, "done", flush=True)


if __name__ == "__main__":
    main()
