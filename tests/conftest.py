"""Fixtures: paths to the shared KITTI clips (skipped when absent) and tiny generated datasets."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

from leovr.paths import shared_data_dir

SHARED = shared_data_dir()
KITTI_RAW = SHARED / "kitti_raw"
KITTI_ODOM = SHARED / "kitti_odometry" / "sequences" / "06"
KITTI_RAW_POSES = SHARED / "kitti_raw_0013"  # the second drive: OXTS poses and scan start / end times

needs_shared = pytest.mark.skipif(
    not KITTI_RAW.is_dir() or not KITTI_ODOM.is_dir(),
    reason=f"shared KITTI clips not found at {SHARED} (set LEOVR_SHARED_DATA or place ../shared/data)",
)

needs_posed_drive = pytest.mark.skipif(
    not KITTI_RAW_POSES.is_dir(),
    reason=f"the KITTI raw drive with OXTS poses not found at {KITTI_RAW_POSES} (set LEOVR_SHARED_DATA or place "
    "../shared/data)",
)

# KITTI-like axes: LiDAR x forward, y left, z up; camera x right, y down, z forward.
R_CAM_LIDAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
FX, CX, CY = 200.0, 80.0, 40.0
W, H = 160, 80


def ring_scan(n_rings: int = 64, per_ring: int = 360, radius: float = 10.0, seed: int = 0) -> np.ndarray:
    """A spinning-LiDAR scan stored ring after ring (top ring first), azimuth rising from -pi."""
    rng = np.random.default_rng(seed)
    el = np.radians(np.linspace(2.0, -24.8, n_rings))
    az = np.linspace(-np.pi, np.pi, per_ring, endpoint=False)
    E, A = np.meshgrid(el, az, indexing="ij")
    r = radius + 0.01 * rng.standard_normal(E.shape)
    pts = np.stack([r * np.cos(E) * np.cos(A), r * np.cos(E) * np.sin(A), r * np.sin(E), np.full(E.shape, 0.5)], -1)
    return pts.reshape(-1, 4).astype(np.float32)


def write_kitti_raw(root: Path, frames: int = 3) -> Path:
    """A minimal KITTI raw sync drive with calibration; returns the drive folder."""
    date = root / "2011_01_01"
    drive = date / "2011_01_01_drive_0001_sync"
    (drive / "image_02" / "data").mkdir(parents=True)
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    P = f"{FX} 0 {CX} 0 0 {FX} {CY} 0 0 0 1 0"
    (date / "calib_cam_to_cam.txt").write_text(
        f"calib_time: 09-Jan-2012 13:57:47\nP_rect_02: {P}\nR_rect_00: 1 0 0 0 1 0 0 0 1\n"
    )
    R = " ".join(f"{v:g}" for v in R_CAM_LIDAR.ravel())
    (date / "calib_velo_to_cam.txt").write_text(f"calib_time: 15-Mar-2012 11:37:16\nR: {R}\nT: 0 0 0\n")
    rng = np.random.default_rng(1)
    for i in range(frames):
        img = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
        cv2.imwrite(str(drive / "image_02" / "data" / f"{i:010d}.png"), img)
        ring_scan(seed=i).tofile(drive / "velodyne_points" / "data" / f"{i:010d}.bin")
    return drive


@pytest.fixture
def kitti_raw_tiny(tmp_path: Path) -> Path:
    return write_kitti_raw(tmp_path)


@pytest.fixture(scope="session")
def straight_mid40_drive(tmp_path_factory):
    """A straight 9-frame Mid-40 drive at 30 km/h (seed 21): buildings beside the road, outside the 38-degree
    cone; the sequence and its frames by index (motion stereo and the photometric correction)."""
    from leovr.config import SimulateConfig
    from leovr.data import open_sequence
    from leovr.sim.simulate import simulate

    out = tmp_path_factory.mktemp("straight_mid40") / "seq"
    simulate(SimulateConfig(scenario="straight", lidar="mid40", frames=9, seed=21), out, progress=False)
    seq = open_sequence(out)
    return seq, {i: seq[i] for i in range(len(seq))}


@contextmanager
def killed_after_saves(n: int) -> Iterator[None]:
    """A refine run inside the block is killed (KeyboardInterrupt) right after its n-th progress save (a frame's
    files, then the progress record naming it), as a user's Ctrl-C or a lost machine would leave it; the block
    expects that interrupt. The run writes in its own thread here, so the interrupt comes at that moment."""
    from leovr.pipeline import refine, refine_record

    write, writer, calls = refine_record.write_frame_files, refine.FrameWriter, []

    def killed(*args):
        write(*args)
        calls.append(args)
        if len(calls) == n:
            raise KeyboardInterrupt

    refine_record.write_frame_files = killed
    refine.FrameWriter = lambda threaded: writer(False)
    try:
        with pytest.raises(KeyboardInterrupt):
            yield
    finally:
        refine_record.write_frame_files, refine.FrameWriter = write, writer
