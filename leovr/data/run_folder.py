"""A finished `leovr refine` run read back: the sequence it was made from, its frames, poses and depth maps
(for the recording and the map, which start from a run's outputs)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.data.io import read_json_object
from leovr.data.kitti_common import read_kitti_poses
from leovr.data.run_info import run_frame_png
from leovr.data.sequence import Sequence
from leovr.errors import DataError


@dataclass
class RunFolder:
    """A finished run: `indices` are the positions in `seq` of its frames, `poses` their camera poses
    (camera to world, one per index)."""

    path: Path
    seq: Sequence
    poses: np.ndarray
    indices: list[int]

    def png(self, folder: str, n: int) -> Path:
        """The PNG of the run's n-th frame in `folder` (depth, depth_generator, sigma, ...)."""
        return run_frame_png(self.path, folder, self.indices[n])


def is_finished_run(path: Path) -> bool:
    return (Path(path) / "metrics.json").is_file() and (Path(path) / "poses_kitti.txt").is_file()


def read_run(run: Path) -> RunFolder:
    """The run in `run`; one clear error when it did not finish or its files disagree with each other or with
    its sequence."""
    run = Path(run)
    if not run.is_dir():
        raise DataError(run, "no such folder" if not run.exists() else "not a folder (a leovr refine run is one)")
    if not is_finished_run(run):
        if (run / "run.json").is_file():
            missing = [n for n in ("metrics.json", "poses_kitti.txt") if not (run / n).is_file()]
            raise DataError(
                run, f"this run did not finish (no {' or '.join(missing)} yet): resume it with its command and --resume"
            )
        raise DataError(run, "not a leovr refine run (no metrics.json and poses_kitti.txt)")
    seq = open_sequence(run_sequence(run))
    poses = read_kitti_poses(run / "poses_kitti.txt")
    progress = read_json_object(run / "progress.json") if (run / "progress.json").is_file() else {}
    indices = sorted(int(k) for k in progress.get("poses", {})) or list(range(len(poses)))
    if len(poses) < len(indices):
        raise DataError(
            run / "poses_kitti.txt",
            f"{len(poses)} poses for the run's {len(indices)} frames (progress.json): the run's files disagree",
        )
    if indices and max(indices) >= len(seq):
        raise DataError(
            run,
            f"the run has frames up to {max(indices)} but its sequence {seq.path} has "
            f"{len(seq)} frames: not the recording the run was made from",
        )
    return RunFolder(run, seq, poses[: len(indices)], indices)


def run_sequence(run: Path) -> Path:
    """The sequence a run was made from. Runs written before leovr recorded absolute paths hold the
    path as typed; it is then looked up from the current folder and from each folder above the run."""
    doc = read_json_object(run / "metrics.json")
    if "sequence" not in doc:
        raise DataError(run / "metrics.json", "has no 'sequence' field")
    p = Path(doc["sequence"])
    if p.is_absolute() or p.exists():
        return p
    for base in run.resolve().parents:
        if (base / p).exists():
            return base / p
    return p  # open_sequence names it as missing
