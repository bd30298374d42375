"""Lazy sequences: a reader loads a frame only when it is asked for."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from leovr.data.io import read_image, read_point_file
from leovr.data.records import Frame, SequenceInfo
from leovr.errors import DataError
from leovr.lidar.sweep import azimuth_times


class Sequence(ABC):
    """A recorded sequence with a length, integer indexing, slicing and a summary.

    Subclasses implement `_num_frames` and `_load`; everything else is shared.
    """

    name: str = "sequence"
    path: Path

    @abstractmethod
    def _num_frames(self) -> int: ...

    @abstractmethod
    def _load(self, i: int) -> Frame: ...

    # optional capabilities, overridden by readers that know them without loading data
    has_lidar: bool = False
    _image_size: tuple[int, tuple[int, int]] | None = None  # (frame, rows x cols) of the first frame loaded
    has_poses: bool = False
    has_depth: bool = False
    rate_hz: float = 10.0
    # the camera's height above the road (m), where the recording says it: camera-only runs read their
    # metric scale from the road plane (`odometry.ground_plane`); None: unknown
    camera_height_m: float | None = None

    def __len__(self) -> int:
        return self._num_frames()

    def __getitem__(self, key: int | slice) -> Frame | "SequenceView":
        if isinstance(key, slice):
            return SequenceView(self, list(range(len(self)))[key])
        n = len(self)
        i = int(key)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {key} out of range for {n} frames in {self.path}")
        frame = self._load(i)
        self._check_size(i, frame)
        return frame

    def pose(self, i: int) -> np.ndarray | None:
        """Frame i's ground-truth pose (camera to world), None without poses."""
        return self[i].T_world_cam if self.has_poses else None

    def _check_size(self, i: int, frame: Frame) -> None:
        """Every image of a sequence has one size: its one calibration cannot fit two (the first frame
        loaded sets the size)."""
        size = frame.image.shape[:2]
        seen = self._image_size
        if seen is None:
            self._image_size = (i, size)
        elif seen[1] != size:
            where = self.image_path(i) or f"{self.path} frame {i}"
            raise DataError(
                where,
                f"image is {size[1]}x{size[0]} but frame {seen[0]} of the same sequence is "
                f"{seen[1][1]}x{seen[1][0]}; one calibration cannot fit both",
            )

    def image_path(self, i: int) -> Path | None:
        """The image file of frame `i`, for error messages (None for readers without one file per image)."""
        return None

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def timestamps(self) -> np.ndarray:
        """Frame timestamps in seconds; readers override when they can avoid loading images."""
        return np.array([f.timestamp for f in self])

    def frame_numbers(self) -> list[int]:
        """The recording's own number of each frame (its file name); readers whose files are numbered
        with gaps override this. Default: the position."""
        return list(range(len(self)))

    def info(self) -> SequenceInfo:
        """Summarise the sequence by loading its first frame (and, when that one has no LiDAR return, the
        first of the next ten that has, for the scans' figures)."""
        first = self[0] if len(self) else None
        scan = first
        for i in range(1, min(len(self), 11)):
            if not self.has_lidar or (scan is not None and scan.points is not None and len(scan.points)):
                break
            scan = self[i]
        pts = 0 if scan is None or scan.points is None else len(scan.points)
        return SequenceInfo(
            reader=self.name,
            path=str(self.path),
            frames=len(self),
            width=first.width if first is not None else 0,
            height=first.height if first is not None else 0,
            channels=1 if first is None or first.image.ndim == 2 else int(first.image.shape[2]),
            rate_hz=float(self.rate_hz),
            has_lidar=self.has_lidar,
            points_per_scan=pts,
            has_point_times=scan is not None and scan.point_times is not None,
            has_poses=self.has_poses,
            has_depth=self.has_depth,
        )


class RecordedSequence(Sequence):
    """A recording with one camera calibration, per-frame times and optional poses: readers fill `_times`, `_poses`
    (F x 4 x 4 or None), `K` and `T_cam_lidar`; `_frame` builds frame i from its image and scan."""

    _times: np.ndarray
    _poses: np.ndarray | None
    K: np.ndarray
    T_cam_lidar: np.ndarray

    def timestamps(self) -> np.ndarray:
        return self._times.copy()

    def pose(self, i: int) -> np.ndarray | None:
        return None if self._poses is None else self._poses[i]

    def _frame(
        self, i: int, image: np.ndarray, points: np.ndarray | None, point_times: np.ndarray | None = None, **extra
    ) -> Frame:
        """Frame i from its image and scan, with the sequence's calibration, time and pose."""
        return Frame(
            index=i,
            timestamp=float(self._times[i]),
            image=image,
            K=self.K,
            T_cam_lidar=self.T_cam_lidar,
            points=points,
            point_times=point_times,
            T_world_cam=None if self._poses is None else self._poses[i],
            **extra,
        )


class FileSequence(RecordedSequence):
    """A sequence backed by per-frame image and scan files, timestamps and optional poses.

    Readers fill `image_files`, `scan_files` (empty without LiDAR), `_times`, `_poses` (F x 4 x 4 or
    None), `K` and `T_cam_lidar`, and `sweeps` where the recording stamps the start and end of each
    spinning LiDAR's sweep (F x 2, seconds from the frame's image; each point's time then follows from its
    azimuth); loading a frame is then the same for all of them.
    """

    sweeps: np.ndarray | None = None

    image_files: list[Path]
    scan_files: list[Path]

    def _num_frames(self) -> int:
        return len(self.image_files)

    def image_path(self, i: int) -> Path | None:
        return self.image_files[i]

    def _load(self, i: int) -> Frame:
        points = read_point_file(self.scan_files[i], 4) if self.scan_files else None
        times = None
        if points is not None and self.sweeps is not None:
            start, end = self.sweeps[i]
            times = start + azimuth_times(points, end - start)
        return self._frame(i, read_image(self.image_files[i]), points, times)


class SequenceView(Sequence):
    """A slice of another sequence; frames keep their original index."""

    def __init__(self, base: Sequence, indices: list[int]) -> None:
        self.base = base
        self.indices = indices
        self.name = base.name
        self.path = base.path
        self.has_lidar = base.has_lidar
        self.has_poses = base.has_poses
        self.has_depth = base.has_depth
        self.rate_hz = base.rate_hz

    def _num_frames(self) -> int:
        return len(self.indices)

    def _load(self, i: int) -> Frame:
        return self.base[self.indices[i]]

    def timestamps(self) -> np.ndarray:
        return self.base.timestamps()[self.indices]

    def pose(self, i: int) -> np.ndarray | None:
        return self.base.pose(self.indices[i])

    def frame_numbers(self) -> list[int]:
        numbers = self.base.frame_numbers()
        return [numbers[i] for i in self.indices]
