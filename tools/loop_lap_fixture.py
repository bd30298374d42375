"""Writes tests/data/loop_lap_mid40.npz from a `leovr refine --loop-closure` run on a rendered lap: the window's
poses before loop closure, its step covariances, the accepted loops and the ground-truth poses. The loop pose
graph's tests replay it without running the pipeline.

    python tools/loop_lap_fixture.py RUN SEQUENCE [OUT]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.pipeline.refine_outputs import Progress


def main(run: Path, seq_dir: Path, out: Path) -> None:
    state = Progress.load(run / "progress.json")
    indices = sorted(state.poses_no_loop)
    at = {i: n for n, i in enumerate(indices)}
    step_cov = np.stack([np.full((6, 6), np.nan) if c is None else c for c in state.covariances(indices)])
    loops = [r for r in json.loads((run / "loops.json").read_text())["loops"] if r["accepted"]]
    seq = open_sequence(seq_dir)
    np.savez_compressed(
        out,
        poses=state.stacked("poses_no_loop", indices),
        step_cov=step_cov,
        loop_pairs=np.array([(at[r["frame"]], at[r["candidate"]]) for r in loops]),
        loop_T=np.stack([np.array(r["T_j_i"]) for r in loops]),
        truth=np.stack([seq.pose(i) for i in indices]),
    )


if __name__ == "__main__":
    main(
        Path(sys.argv[1]),
        Path(sys.argv[2]),
        Path(sys.argv[3] if len(sys.argv) > 3 else "tests/data/loop_lap_mid40.npz"),
    )
