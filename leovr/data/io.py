"""Low-level file I/O with validation: every failure names the file and the problem."""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from leovr.errors import DataError


def require_file(path: Path, what: str) -> Path:
    """Return `path` if it is a readable file, else raise a DataError saying what was expected."""
    if not path.is_file():
        raise DataError(path, f"missing {what}")
    if not os.access(path, os.R_OK):
        raise DataError(path, f"{what} is not readable")
    return path


def read_image(path: Path, gray: bool = False) -> np.ndarray:
    """Read an 8-bit image as RGB (H x W x 3) or gray (H x W); gray files stay gray."""
    require_file(path, "image")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise DataError(path, "corrupt or unsupported image (OpenCV could not decode it)")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
    return img


DEPTH_SCALE = 256.0  # KITTI depth-completion convention: uint16 = metres x 256, 0 = unknown, up to 255.99 m
LEGACY_DEPTH_SCALE = 1000.0  # millimetres: what leovr wrote before (cut at 65.5 m); read where a file says so


def read_depth_png(path: Path, scale: float = DEPTH_SCALE, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a 16-bit depth PNG as float32 metres (0 = unknown); `scale` is units per metre; with
    `shape` (rows, cols) a map of another size is refused."""
    require_file(path, "depth image")
    d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if d is None:
        raise DataError(path, "corrupt depth image (OpenCV could not decode it)")
    if d.dtype != np.uint16 or d.ndim != 2:
        raise DataError(path, f"depth image must be single-channel uint16, got {d.dtype} with shape {d.shape}")
    if shape is not None and d.shape != tuple(shape):
        raise DataError(path, f"depth image is {d.shape[1]}x{d.shape[0]}, the frame is {shape[1]}x{shape[0]}")
    return d.astype(np.float32) / scale


def format_max_depth(scale: float = DEPTH_SCALE) -> float:
    """The largest depth (m) a uint16 depth PNG holds at `scale` units per metre (255.99 m at 256)."""
    return 65535.0 / scale


def depth_to_uint16(depth: np.ndarray, scale: float = DEPTH_SCALE) -> np.ndarray:
    """Metres to uint16 units (metres x 256 by default, the KITTI depth-completion convention).

    Non-finite or non-positive values become 0 (unknown); depths beyond the format's range
    (255.99 m at 256 units per metre) saturate at 65535 rather than being lost.
    """
    d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0, neginf=0.0) * scale
    d = np.where(d > 0, np.minimum(np.round(d), 65535), 0)
    return d.astype(np.uint16)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """Write through a temporary file in the same folder, then rename: readers never see half a file.
    The file gets the mode a plain `open` would give it (0666 less the user's umask), not mkstemp's 0600."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def read_yaml(path: Path) -> object:
    """A YAML file's contents; an unreadable file, text that is not UTF-8 or invalid YAML is one clear error
    naming the file (and the line)."""
    import yaml

    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DataError(path, f"cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise DataError(path, f"not UTF-8 text (byte {exc.start}: {exc.object[exc.start : exc.start + 1]!r})") from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise DataError(path, f"invalid YAML{where}: {problem}") from exc


def check_output_dir(out: Path) -> Path:
    """Create the output folder `out` if needed and prove it writable, before any work starts: an
    output path that is a file or a read-only folder fails now, not after hours of computing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise DataError(out, "output path is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".leovr-write-test.", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DataError(out, f"output folder cannot be written: {exc.strerror or exc}") from exc
    return out


def check_output_file(path: Path) -> Path:
    """Prove a file can be written at `path` before any work starts (its folder created if needed): a path
    that is a folder, lies under a file, or sits in a read-only folder fails now, not after the run."""
    path = Path(path)
    if path.is_dir():
        raise DataError(path, "output path is a folder, not a file")
    blocker = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocker is not None:
        raise DataError(path, f"output path lies under {blocker}, which is a file")
    check_output_dir(path.parent)
    return path


def depth_png_bytes(units: np.ndarray, path: Path) -> bytes:
    """A uint16 depth map (`depth_to_uint16`) encoded as PNG, for `path` (named by the error)."""
    ok, buf = cv2.imencode(".png", units)
    if not ok:
        raise DataError(path, "could not write depth PNG")
    return buf.tobytes()


def write_png_bytes(path: Path, data: bytes) -> None:
    """Write an encoded PNG atomically."""
    atomic_write(path, lambda tmp: tmp.write_bytes(data))


def write_depth_png(path: Path, depth: np.ndarray, scale: float = DEPTH_SCALE) -> None:
    """Write depth in metres as a uint16 PNG (metres x 256 by default), atomically."""
    write_png_bytes(path, depth_png_bytes(depth_to_uint16(depth, scale), path))


def write_image(path: Path, image: np.ndarray) -> None:
    """Write an RGB or gray uint8 image atomically."""

    def _write(tmp: Path) -> None:
        img = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
        if not cv2.imwrite(str(tmp), img):
            raise DataError(path, "could not write image")

    atomic_write(path, _write)


def require_intrinsics(K: np.ndarray, source: Path) -> np.ndarray:
    """The 3 x 3 camera matrix, refused (naming `source`) unless finite with positive focal lengths."""
    if not np.isfinite(K).all():
        raise DataError(source, "the camera matrix holds NaN or infinite values")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise DataError(source, f"the camera matrix needs positive focal lengths, not fx={K[0, 0]:g}, fy={K[1, 1]:g}")
    return K


def require_finite_rows(rows: np.ndarray, path: Path) -> np.ndarray:
    """`rows` (one per line of `path`) unchanged, or a DataError naming the first line with NaN or inf."""
    bad = np.nonzero(~np.isfinite(rows).all(1))[0]
    if len(bad):
        raise DataError(path, f"line {int(bad[0]) + 1} holds NaN or infinite values ({len(bad)} line(s) in all)")
    return rows


def read_json_object(path: Path) -> dict:
    """A JSON file holding an object; a missing, corrupt or non-object file is a DataError naming it."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(path, f"not readable JSON: {exc}") from exc
    if not isinstance(doc, dict):
        raise DataError(path, "must hold a JSON object")
    return doc


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically."""
    atomic_write(path, lambda tmp: tmp.write_text(text))


def read_point_file(path: Path, fields: int = 4) -> np.ndarray:
    """Read a float32 point file (`fields` values per point), dropping NaN/inf points with a warning.

    Raises a DataError when the file is missing or its size is not a whole number of points.
    """
    require_file(path, "LiDAR scan")
    size = path.stat().st_size
    rec = 4 * fields
    if size % rec:
        raise DataError(path, f"size {size} bytes is not a multiple of {rec} bytes ({fields} float32 per point)")
    pts = np.fromfile(path, dtype=np.float32).reshape(-1, fields)
    return clean_points(pts, path)


MIN_SCAN_POINTS = 100  # fewer and a scan is suspect (KISS-ICP skips such scans too)


def clean_points(pts: np.ndarray, source: str | Path) -> np.ndarray:
    """Drop non-finite points (warning with the source name); an empty result is a frame without returns,
    as a bag's image without a scan is (a warning names it)."""
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        warnings.warn(f"{source}: dropped {int((~finite).sum())} NaN or infinite points", stacklevel=3)
        pts = pts[finite]
    if len(pts) == 0:
        warnings.warn(f"{source}: empty LiDAR scan (no valid point): the frame has no LiDAR return", stacklevel=3)
    elif len(pts) < MIN_SCAN_POINTS:
        warnings.warn(
            f"{source}: only {len(pts)} valid point(s); a LiDAR sweep has thousands (a truncated file?), "
            "so this frame's depth and LiDAR odometry rest on almost nothing",
            stacklevel=3,
        )
    return pts


def associate(a: np.ndarray, b: np.ndarray, max_dt: float) -> np.ndarray:
    """Index into sorted `b` of the nearest timestamp for each entry of `a`, -1 when farther than max_dt."""
    if len(b) == 0:
        return np.full(len(a), -1)
    j = np.searchsorted(b, a)
    lo, hi = np.clip(j - 1, 0, len(b) - 1), np.clip(j, 0, len(b) - 1)
    best = np.where(np.abs(b[lo] - a) <= np.abs(b[hi] - a), lo, hi)
    return np.where(np.abs(b[best] - a) <= max_dt, best, -1)


def check_timestamps(t: np.ndarray, source: Path) -> np.ndarray:
    """Timestamps must be finite and strictly increasing."""
    t = np.asarray(t, np.float64)
    if not np.isfinite(t).all():
        raise DataError(source, "timestamps contain NaN or infinite values")
    back = np.where(np.diff(t) <= 0)[0]
    if len(back):
        i = int(back[0])
        raise DataError(source, f"timestamps go backwards (or repeat) at entry {i + 1}: {t[i]:.6f} -> {t[i + 1]:.6f}")
    return t


def read_timestamp_file(path: Path, frames: int) -> np.ndarray:
    """One time in seconds per line; finite, increasing and one per frame."""
    try:
        t = np.loadtxt(path, ndmin=1)
    except (OSError, ValueError) as exc:
        raise DataError(path, f"unreadable timestamps: {exc}") from exc
    check_timestamps(t, path)
    if len(t) != frames:
        raise DataError(path, f"{len(t)} timestamps for {frames} frames")
    return t


def read_matrix_rows(path: Path, what: str) -> dict[str, np.ndarray]:
    """Parse `key: v v v ...` calibration files (KITTI style) into float arrays."""
    require_file(path, what)
    out: dict[str, np.ndarray] = {}
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(path, f"unreadable {what}: {exc}") from exc
    for n, line in enumerate(lines, 1):
        if ":" not in line:
            continue
        key, _, val = line.partition(":")
        try:
            out[key.strip()] = np.array([float(v) for v in val.split()])
        except ValueError:
            if key.strip() in ("calib_time",):
                continue
            raise DataError(path, f"line {n}: '{key.strip()}' is not a list of numbers") from None
    return out
