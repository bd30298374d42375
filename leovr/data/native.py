"""The project's native sequence format (documented in docs/formats.md): reader and streaming writer."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from leovr.data.io import (
    DEPTH_SCALE,
    LEGACY_DEPTH_SCALE,
    atomic_write,
    read_depth_png,
    read_image,
    read_point_file,
    read_timestamp_file,
    read_yaml,
    require_file,
    require_finite_rows,
    require_intrinsics,
    write_depth_png,
    write_image,
    write_text,
)
from leovr.data.records import Frame
from leovr.data.sequence import FileSequence, Sequence
from leovr.errors import DataError
from leovr.geometry import pose_from_tum, pose_to_tum

FORMAT = "leovr-native"
VERSION = 1
ALLOWED_FIELDS = {"x", "y", "z", "intensity", "time"}
# what a native folder holds, the description first (NativeWriter's `overwrite` removes them in this order)
SEQUENCE_PARTS = ("sequence.yaml", "images", "lidar", "depth", "masks", "timestamps.txt", "poses_tum.txt")


def is_native(path: Path) -> bool:
    return (path / "sequence.yaml").is_file()


def frame_name(i: int, ext: str) -> str:
    return f"{i:06d}.{ext}"


def read_tum_poses(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A TUM trajectory file (t tx ty tz qx qy qz qw) as timestamps and F x 4 x 4 poses."""
    require_file(path, "TUM pose file")
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise DataError(path, f"unreadable TUM poses: {exc}") from exc
    if rows.shape[1] != 8:
        raise DataError(path, f"expected 8 columns (t tx ty tz qx qy qz qw), got {rows.shape[1]}")
    require_finite_rows(rows, path)
    return rows[:, 0], np.stack([pose_from_tum(r[1:]) for r in rows]) if len(rows) else np.zeros((0, 4, 4))


def write_tum_poses(path: Path, stamps: np.ndarray, poses: np.ndarray) -> None:
    """Write F x 4 x 4 poses as a TUM trajectory, atomically."""
    lines = [f"{t:.6f} " + " ".join(f"{v:.9f}" for v in pose_to_tum(T)) for t, T in zip(stamps, poses)]
    write_text(path, "\n".join(lines) + ("\n" if lines else ""))


def _matrix(meta: dict, key: str, shape: tuple[int, int], path: Path) -> np.ndarray:
    try:
        m = np.array(meta[key], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise DataError(path, f"missing or non-numeric '{key}'") from None
    if m.shape != shape:
        raise DataError(path, f"'{key}' must be {shape[0]}x{shape[1]}, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise DataError(path, f"'{key}' holds NaN or infinite values")
    return m


def _number(d: dict, key: str, default, kind: type, source: Path):
    """A numeric field of sequence.yaml: a whole number (`kind=int`) or a positive finite one (`float`)."""
    v = d.get(key, default)
    try:
        out = kind(v)
        if isinstance(v, bool) or not np.isfinite(out) or (kind is float and out <= 0):
            raise ValueError
    except (TypeError, ValueError):
        raise DataError(
            source, f"'{key}' must be a {'whole' if kind is int else 'positive'} number, not {v!r}"
        ) from None
    if kind is int and out != float(v):
        raise DataError(source, f"'{key}' must be a whole number, not {v!r}")
    return out


class NativeSequence(FileSequence):
    """Reader for folders holding `sequence.yaml`."""

    name = "native"

    def __init__(self, path: str | Path) -> None:
        self.path = path = Path(path)
        meta_file = require_file(path / "sequence.yaml", "sequence description")
        meta = read_yaml(meta_file)
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise DataError(meta_file, f"not a {FORMAT} description (missing 'format: {FORMAT}')")
        version = _number(meta, "version", VERSION, int, meta_file)
        if version > VERSION:
            raise DataError(meta_file, f"format version {version} is newer than this leovr reads ({VERSION})")
        self.meta = meta
        cam = meta.get("camera") or {}
        if not isinstance(cam, dict):
            raise DataError(meta_file, "'camera' must be a mapping (K, width, height)")
        self.K = require_intrinsics(_matrix(cam, "K", (3, 3), meta_file), meta_file)
        self.width, self.height = _number(cam, "width", 0, int, meta_file), _number(cam, "height", 0, int, meta_file)
        self.rate_hz = _number(meta, "rate_hz", 10.0, float, meta_file)
        if cam.get("height_above_road_m") is not None:
            self.camera_height_m = _number(cam, "height_above_road_m", None, float, meta_file)
        n = _number(meta, "frames", -1, int, meta_file)
        self.image_files = sorted((path / "images").glob("*.png"))
        if n < 0 or len(self.image_files) != n:
            raise DataError(path / "images", f"{len(self.image_files)} images but sequence.yaml says frames: {n}")
        self.stems = [p.stem for p in self.image_files]  # the recording's frame numbers (gaps kept)
        lidar = meta.get("lidar")
        if lidar and not isinstance(lidar, dict):
            raise DataError(meta_file, "'lidar' must be a mapping (name, fields, T_cam_lidar)")
        self.has_lidar = bool(lidar)
        self.fields: list[str] = []
        self.T_cam_lidar = np.eye(4)
        if lidar:
            self.fields = list(lidar.get("fields", ["x", "y", "z", "intensity"]))
            if self.fields[:3] != ["x", "y", "z"] or not set(self.fields) <= ALLOWED_FIELDS:
                raise DataError(meta_file, f"lidar.fields must start with x, y, z and use {sorted(ALLOWED_FIELDS)}")
            self.T_cam_lidar = _matrix(lidar, "T_cam_lidar", (4, 4), meta_file)
            self.scan_files = sorted((path / "lidar").glob("*.bin"))
            if len(self.scan_files) != n:
                raise DataError(path / "lidar", f"{len(self.scan_files)} scans but {n} images")
            record = 4 * len(self.fields)  # float32 per field
            odd = next((p for p in self.scan_files if p.stat().st_size % record), None)
            if odd is not None:
                raise DataError(
                    odd,
                    f"size {odd.stat().st_size} bytes is not a whole number of {len(self.fields)}-field "
                    f"points ({record} bytes each, lidar.fields in sequence.yaml)",
                )
            unpaired = sorted(set(self.stems) ^ {p.stem for p in self.scan_files})
            if unpaired:
                raise DataError(
                    path / "lidar", f"scans and images are numbered differently ({', '.join(unpaired[:5])})"
                )
        elif (path / "lidar").is_dir() and any((path / "lidar").glob("*.bin")):
            warnings.warn(
                f"{meta_file}: no 'lidar:' entry, so the scans in {path / 'lidar'} are not read "
                "(camera only); add lidar: {fields, T_cam_lidar} to use them",
                stacklevel=2,
            )
        ts = path / "timestamps.txt"
        self._times = read_timestamp_file(ts, n) if ts.is_file() else np.arange(n) / self.rate_hz
        self._poses = None
        pose_file = path / "poses_tum.txt"
        if pose_file.is_file():
            _, self._poses = read_tum_poses(pose_file)
            if len(self._poses) != n:
                raise DataError(pose_file, f"{len(self._poses)} poses for {n} frames")
        self.has_poses = self._poses is not None
        self.has_depth = (path / "depth").is_dir()
        # PNG units per metre; files from before the key existed were written in millimetres
        self.depth_scale = _number(meta, "depth_scale", LEGACY_DEPTH_SCALE, float, meta_file)
        self.has_masks = (path / "masks").is_dir()

    def frame_numbers(self) -> list[int]:
        """The file names' numbers (the recording's own, gaps kept); positions where a name is not a number."""
        return [int(s) if s.isdigit() else k for k, s in enumerate(self.stems)]

    def _load(self, i: int) -> Frame:
        """As FileSequence, with the scan's own fields (a per-point time among them), depth and masks."""
        points = times = None
        if self.has_lidar:
            raw = read_point_file(self.scan_files[i], len(self.fields))
            keep = [k for k, f in enumerate(self.fields) if f != "time"]
            points = np.ascontiguousarray(raw[:, keep[:4]])
            if "time" in self.fields:
                times = raw[:, self.fields.index("time")].astype(np.float64)
        image = read_image(self.image_files[i])
        depth = None
        if self.has_depth:
            depth = read_depth_png(self.path / "depth" / f"{self.stems[i]}.png", self.depth_scale, image.shape[:2])
        mask = None
        if self.has_masks:
            mask = read_image(self.path / "masks" / f"{self.stems[i]}.png", gray=True) > 0
        if self.width and image.shape[:2] != (self.height, self.width):
            raise DataError(
                self.image_files[i],
                f"image is {image.shape[1]}x{image.shape[0]}, sequence.yaml says {self.width}x{self.height}",
            )
        return self._frame(i, image, points, times, depth=depth, moving_mask=mask)


class NativeWriter:
    """Stream frames into a native-format folder; `close()` writes the description last.

    Frames must be written in order. Each file is written atomically; sequence.yaml appears only once
    all frames are on disk, so a half-written folder is never mistaken for a complete sequence. A folder
    that already holds a sequence is refused, or with `overwrite` cleared of it first.
    """

    def __init__(
        self,
        out: str | Path,
        name: str = "sequence",
        rate_hz: float = 10.0,
        camera_name: str = "camera",
        lidar_name: str = "lidar",
        extra: dict[str, Any] | None = None,
        depth_scale: float = DEPTH_SCALE,
        camera_height_m: float | None = None,
        overwrite: bool = False,
    ) -> None:
        self.out = Path(out)
        held = [n for n in SEQUENCE_PARTS if (self.out / n).exists()]
        if held and not overwrite:
            what = (
                "already holds a sequence"
                if "sequence.yaml" in held
                else "holds an unfinished sequence (no sequence.yaml: an interrupted write?)"
            )
            raise DataError(
                self.out,
                f"{what} ({', '.join(held)}); write into a new or empty folder, or replace it "
                "(convert --overwrite; frames left from it would mix with the new ones)",
            )
        for name in held:  # the description first: a half-cleared folder is never taken for a sequence
            part = self.out / name
            shutil.rmtree(part) if part.is_dir() else part.unlink()
        self.out.mkdir(parents=True, exist_ok=True)
        self.name, self.rate_hz = name, rate_hz
        self.camera_name, self.lidar_name = camera_name, lidar_name
        self.extra = extra or {}
        self.depth_scale = depth_scale
        self.camera_height_m = camera_height_m
        self.stamps: list[float] = []
        self.poses: list[np.ndarray] = []
        self.first: Frame | None = None
        self.fields: list[str] = []  # fixed by the first scan with returns
        self.empty_only = True  # every scan so far had no return
        self.numbers: list[int] = []

    def write(self, frame: Frame, number: int | None = None) -> None:
        """Write the next frame, its files named by `number` (the recording's frame number; default: its
        position); numbers must increase."""
        i = len(self.stamps) if number is None else int(number)
        if self.numbers and i <= self.numbers[-1]:
            raise ValueError(f"frame number {i} after {self.numbers[-1]}: frames must be written in order")
        self.numbers.append(i)
        if self.first is None:
            self.first = frame
        write_image(self.out / "images" / frame_name(i, "png"), frame.image)
        if frame.points is not None:
            cols = [frame.points[:, :3]]
            fields = ["x", "y", "z"]
            if frame.points.shape[1] > 3:
                cols.append(frame.points[:, 3:4])
                fields.append("intensity")
            if frame.point_times is not None:
                cols.append(np.asarray(frame.point_times)[:, None])
                fields.append("time")
            empty = len(frame.points) == 0  # a frame without returns: an empty file, whatever the fields
            if empty:
                self.fields = self.fields or fields  # until a scan with returns sets them
            elif self.empty_only:
                self.fields = fields
            elif fields != self.fields:
                raise ValueError(f"frame {i}: LiDAR fields {fields} differ from the first frame's {self.fields}")
            self.empty_only = self.empty_only and empty
            data = np.hstack(cols).astype(np.float32) if not empty else np.zeros(0, np.float32)
            atomic_write(self.out / "lidar" / frame_name(i, "bin"), lambda tmp: data.tofile(tmp))
        if frame.depth is not None:
            write_depth_png(self.out / "depth" / frame_name(i, "png"), frame.depth, self.depth_scale)
        if frame.moving_mask is not None:
            write_image(self.out / "masks" / frame_name(i, "png"), frame.moving_mask.astype(np.uint8) * 255)
        self.stamps.append(frame.timestamp)
        if frame.T_world_cam is not None:
            self.poses.append(frame.T_world_cam)

    def close(self) -> Path:
        if self.first is None:
            raise ValueError("no frame was written")
        f = self.first
        stamps = np.array(self.stamps)
        write_text(self.out / "timestamps.txt", "".join(f"{t:.6f}\n" for t in stamps))
        if self.poses:
            if len(self.poses) != len(stamps):
                raise ValueError("either every frame or no frame must carry a pose")
            write_tum_poses(self.out / "poses_tum.txt", stamps, np.stack(self.poses))
        meta: dict[str, Any] = {
            "format": FORMAT,
            "version": VERSION,
            "name": self.name,
            "rate_hz": float(self.rate_hz),
            "frames": len(stamps),
            "depth_scale": float(self.depth_scale),
            "camera": {
                "name": self.camera_name,
                "width": f.width,
                "height": f.height,
                "K": np.asarray(f.K, float).tolist(),
            },
        }
        if self.camera_height_m is not None:
            meta["camera"]["height_above_road_m"] = float(self.camera_height_m)
        if self.fields:
            meta["lidar"] = {
                "name": self.lidar_name,
                "fields": self.fields,
                "T_cam_lidar": np.asarray(f.T_cam_lidar, float).tolist(),
            }
        meta.update(self.extra)
        write_text(self.out / "sequence.yaml", yaml.safe_dump(meta, sort_keys=False))
        return self.out


def write_native(seq: Sequence, out: str | Path, name: str | None = None, overwrite: bool = False) -> Path:
    """Copy any readable sequence into the native format (`overwrite`: replace a sequence already in `out`)."""
    writer = NativeWriter(
        out,
        name=name or Path(seq.path).name,
        rate_hz=seq.rate_hz,
        camera_height_m=seq.camera_height_m,
        overwrite=overwrite,
    )
    for frame, number in zip(seq, seq.frame_numbers()):
        writer.write(frame, number)
    return writer.close()
