"""What `leovr refine` keeps and writes: the resumable progress, the frames' depth PNGs, the pose files and
timing.json (metrics.json is the scoring pass's: `refine_metrics`)."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leovr.data.io import depth_png_bytes, depth_to_uint16, write_png_bytes, write_text
from leovr.data.kitti_common import write_kitti_poses
from leovr.data.native import write_tum_poses
from leovr.data.sequence import Sequence
from leovr.errors import DataError

# per frame, in timing.json as means: the generator (prior included, and the sweep's motion read from the
# images when it is), the front end, the graph update, and the writing of the frames that left the window (depth
# PNGs, progress.json); the scoring pass after the frames is not timed. `total_ms` is their sum (the cost of a
# sequential run); `wall_ms` the frame's time on the run's clock, shorter because the generator of the next frame
# runs while the graph updates
TIMED = ("generator_ms", "frontend_ms", "graph_ms", "output_ms")
WALL = "wall_ms"  # a frame's time on the run's clock (the next frame's generator overlapping this one's graph)
CPU = "cpu_ms"  # the CPU time of every thread of the process over that span (user + system)


@dataclass
class Progress:
    """What has been finished: poses (camera to world) and the front end's choices, per frame index."""

    poses: dict[int, list[float]] = field(default_factory=dict)
    icp_poses: dict[int, list[float]] = field(default_factory=dict)
    sources: dict[int, str] = field(default_factory=dict)
    poses_no_loop: dict[int, list[float]] = field(default_factory=dict)  # before loop closure, when it ran
    times: dict[int, list[float]] = field(default_factory=dict)  # frame -> ms per stage of TIMED
    # frame -> the window's 6 x 6 covariance of the step into it, row by row (odometry.step_covariance)
    step_covariances: dict[int, list[float]] = field(default_factory=dict)
    # frame -> the camera motion its scan was deskewed with, row by row (scans with point times only)
    deskew: dict[int, list[float]] = field(default_factory=dict)

    @classmethod
    def load(cls, path: Path) -> "Progress":
        try:
            d = json.loads(path.read_text())
            if not isinstance(d, dict):
                raise ValueError("not a JSON object")
            d.setdefault("poses_no_loop", {})  # only runs with loop closure have it
            d.setdefault("step_covariances", {})
            d.setdefault("deskew", {})  # runs without a deskewed input have none
            names = ("poses", "icp_poses", "sources", "poses_no_loop", "times", "step_covariances", "deskew")
            keyed = {name: {int(k): v for k, v in d[name].items()} for name in names}
            # 16 finite numbers each (a 4 x 4 pose), 36 for a covariance
            sized = {"poses": 16, "icp_poses": 16, "poses_no_loop": 16, "step_covariances": 36, "deskew": 16}
            for name, size in sized.items():
                bad = [
                    i
                    for i, T in keyed[name].items()
                    if not isinstance(T, list) or len(T) != size or not np.isfinite(np.asarray(T, float)).all()
                ]
                if bad:
                    raise ValueError(f"{name} of frame {bad[0]} is not {size} finite numbers")
            return cls(**keyed)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataError(path, f"cannot resume from this progress file: {exc}") from exc

    def text(self) -> str:
        return json.dumps(self.__dict__) + "\n"

    def save(self, path: Path) -> None:
        write_text(path, self.text())

    def covariances(self, indices: list[int]) -> list[np.ndarray | None]:
        """The window's 6 x 6 covariance of the step into each of `indices` (None where it has none)."""
        kept = self.step_covariances
        return [np.array(kept[i]).reshape(6, 6) if i in kept else None for i in indices]

    def deskew_motion(self, i: int) -> np.ndarray | None:
        """The camera motion frame i's input was deskewed with (None: not deskewed)."""
        return np.array(self.deskew[i]).reshape(4, 4) if i in self.deskew else None

    def stacked(self, name: str, indices: list[int]) -> np.ndarray | None:
        """The poses kept under `name` ("poses", "poses_no_loop") as F x 4 x 4 in the order
        of `indices`; None unless every one of them is there."""
        kept = getattr(self, name)
        if not indices or any(i not in kept for i in indices):
            return None
        return np.stack([np.array(kept[i]).reshape(4, 4) for i in indices])


def write_frame_files(out: Path, name: str, maps: dict[str, np.ndarray], state_path: Path, state: str) -> None:
    """A leaving frame's depth maps (folder -> metres) as PNGs, then the run's progress record that names it.
    A map equal to an earlier one in its PNG units is not encoded again (a spinning LiDAR's refined depth is
    its generator's: a PNG is 10 ms)."""
    encoded: list[tuple[np.ndarray, bytes]] = []
    for folder, depth in maps.items():
        units = depth_to_uint16(depth)
        data = next((png for seen, png in encoded if np.array_equal(seen, units)), None)
        if data is None:
            data = depth_png_bytes(units, out / folder / name)
            encoded.append((units, data))
        write_png_bytes(out / folder / name, data)
    write_text(state_path, state)


def check_replay(out: Path, state: Progress, replayed: dict[int, np.ndarray], tol_m: float = 0.05) -> None:
    """Warn when replaying the finished frames of a resumed run did not give back the poses written
    before the interruption (another leovr version, or the recording changed in between)."""
    written = state.poses_no_loop or state.poses  # as the window pass left them
    gap = {
        i: float(np.linalg.norm(T[:3, 3] - np.array(written[i]).reshape(4, 4)[:3, 3]))
        for i, T in replayed.items()
        if i in written
    }
    if not gap:
        return
    worst = max(gap, key=gap.get)
    if gap[worst] > tol_m:
        warnings.warn(
            f"{out}: resuming replayed the finished frames but frame {worst}'s pose moved {gap[worst]:.2f} m "
            "from the one written before the interruption; the outputs mix two runs: rerun without --resume",
            stacklevel=2,
        )


def input_label(name: str, has_lidar: bool) -> str:
    """What the progress bar and metrics say the graph runs on."""
    if name == "none":
        return "camera only (the recording's LiDAR held out)"
    if not has_lidar:
        return "camera only (no LiDAR)"
    return "own scan" if name == "full" else f"{name} simulated from the scan"


def timing_record(times: dict[int, list[float]], indices: list[int]) -> dict:
    """timing.json: per stage the mean (`generator_ms`, ...), median, p95 and max over the frames, and
    the per-frame series (to see whether a stage grows along the sequence), with each frame's wall and CPU
    time. Runs from before a figure was recorded have none for it: null in the series, left out of the stats."""
    timed = [i for i in indices if i in times]
    width = len(TIMED) + 2
    ms = np.array([list(times[i])[:width] + [np.nan] * (width - len(times[i])) for i in timed], float).reshape(
        -1, width
    )
    stages = {k: np.nan_to_num(ms[:, n]) for n, k in enumerate(TIMED)} | {
        "total_ms": np.nansum(ms[:, : len(TIMED)], axis=1),
        WALL: ms[:, len(TIMED)],
        CPU: ms[:, len(TIMED) + 1],
    }
    record: dict = {k: float(np.mean(v)) if len(v) and np.isfinite(v).all() else None for k, v in stages.items()}
    record["frames_timed"] = len(timed)
    record["stats"] = {
        k: {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
        for k, v in stages.items()
        if len(v) and np.isfinite(v).all()
    }
    record["series"] = {"frame": timed} | {
        k: [None if not np.isfinite(x) else round(float(x), 2) for x in v] for k, v in stages.items()
    }
    return record


def write_outputs(seq: Sequence, indices: list[int], state: Progress, out: Path) -> dict:
    """The poses in KITTI and TUM form and timing.json; returns the timing record (means and spreads, no series)."""
    poses = state.stacked("poses", indices)
    write_kitti_poses(out / "poses_kitti.txt", poses)
    write_tum_poses(out / "poses_tum.txt", seq.timestamps()[indices], poses)
    counts = {s: list(state.sources.values()).count(s) for s in sorted(set(state.sources.values()))}
    timing = timing_record(state.times, indices)
    timing["initial_pose_sources"] = counts
    write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    return {k: v for k, v in timing.items() if k != "series"}  # the series is in timing.json
