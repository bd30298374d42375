"""How much of the moving and static pixels the motion-optical-flow mask keeps, on rendered `dynamic`
sequences with known moving-object masks and ground-truth poses (the mask itself uses only the poses).

    .venv/bin/python tools/flow_mask_stats.py [--seeds 1002 1003 5] [--frames 6] [--lam 1.0]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from leovr.config import SimulateConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T
from leovr.sim.simulate import simulate
from selfsup.flow_mask import motion_flow_mask


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1002, 1003, 5])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--lam", type=float, default=1.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            out = Path(tmp) / f"dyn{seed}"
            simulate(SimulateConfig(scenario="dynamic", lidar="mid40", frames=args.frames, seed=seed), out, progress=False)
            seq = open_sequence(out)
            for i in range(len(seq) - 1):
                a, b = seq[i], seq[i + 1]
                t0 = time.perf_counter()
                m = motion_flow_mask(a.image, b.image, invert_T(b.T_world_cam) @ a.T_world_cam, a.K, args.lam)
                ms = 1000 * (time.perf_counter() - t0)
                mv = a.moving_mask
                moving = f"{m[mv].mean():.2f}" if mv.any() else "-"
                print(f"seed {seed} frame {i}: moving pixels {100 * mv.mean():.1f}%, kept moving {moving}, "
                      f"kept static {m[~mv].mean():.2f}, {ms:.0f} ms")


if __name__ == "__main__":
    main()
