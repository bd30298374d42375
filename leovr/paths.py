"""Where things live: the shared data folder beside the checkout, the user cache."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def shared_data_dir() -> Path:
    """`$LEOVR_SHARED_DATA`, else `../shared/data` beside the checkout (or the working directory)."""
    env = os.environ.get("LEOVR_SHARED_DATA")
    if env:
        return Path(env)
    for base in (REPO_ROOT, Path.cwd()):
        cand = (base.parent / "shared" / "data").resolve()
        if cand.is_dir():
            return cand
    return (REPO_ROOT.parent / "shared" / "data").resolve()


def kitti_raw_dir() -> Path:
    return shared_data_dir() / "kitti_raw"


def kitti_raw_clips() -> list[Path]:
    """Every KITTI raw drive under the shared data folder (each a development clip), by folder name."""
    from leovr.data.kitti_raw import find_drive

    root = shared_data_dir()
    return sorted(p for p in root.iterdir() if p.is_dir() and find_drive(p) is not None) if root.is_dir() else []


def kitti_odometry_dir() -> Path:
    return shared_data_dir() / "kitti_odometry" / "sequences" / "06"


def shipped_checkpoint() -> Path:
    """The depth-generator weights committed with the package."""
    return Path(__file__).resolve().parent / "depth" / "checkpoints" / "generator.pt"


def shipped_vocabulary() -> Path:
    """The ORB bag-of-words vocabulary committed with the package (tools/train_vocabulary.py)."""
    return Path(__file__).resolve().parent.parent / "odometry" / "loop" / "vocabulary.npz"
