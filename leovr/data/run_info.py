"""`run.json`: what a leovr output folder holds and what made it.

It records the depth PNG convention (units per metre), so that files are read back as they were
written (folders written before `run.json` existed hold millimetre PNGs), and the run's identity
(command, every setting, the sequences' contents, the checkpoint's hash, leovr's version), so
that `--resume` continues only the very run that wrote the folder.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from functools import lru_cache
from pathlib import Path

import numpy as np

from leovr import __version__
from leovr.data.io import (
    DEPTH_SCALE,
    LEGACY_DEPTH_SCALE,
    check_output_dir,
    format_max_depth,
    read_depth_png,
    read_json_object,
    write_text,
)
from leovr.data.file_digests import changed_files, digest_of, file_digests
from leovr.errors import DataError, brief

RUN_FILE = "run.json"
INPUTS_FILE = "inputs.json"  # the input files' content digests (naming what changed when a resume is refused)


def depth_png_record(scale: float = DEPTH_SCALE) -> dict:
    return {
        "scale": scale,
        "unit": f"uint16 = metres x {scale:g}, 0 = unknown",
        "max_m": round(format_max_depth(scale), 3),
    }


def write_run_info(out: Path, command: str, **extra) -> None:
    """Write `out/run.json` (the command, leovr's version, the depth PNG convention and `extra`)."""
    body = {"command": command, "leovr_version": __version__, "depth_png": depth_png_record(), **extra}
    write_text(Path(out) / RUN_FILE, json.dumps(plain_json(body), indent=2, allow_nan=False) + "\n")


def plain_json(obj):
    """`obj` with every infinite or NaN number as the string "inf", "-inf" or "nan": strict JSON (a distance
    bin's open end, for one)."""
    if isinstance(obj, float) and obj != obj:
        return "nan"
    if isinstance(obj, float) and obj in (float("inf"), float("-inf")):
        return "inf" if obj > 0 else "-inf"
    if isinstance(obj, dict):
        return {k: plain_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain_json(v) for v in obj]
    return obj


def folder_fingerprint(path: Path) -> str:
    """SHA-1 over the contents of every file under `path` (or of the file itself): what a sequence on disk
    is. Each file is read once and its digest cached by size and modification time (file_digests)."""
    return digest_of(file_digests(path))


def _sha256(path: Path) -> str:
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def run_identity(command: str, settings: dict, sequences: list[Path], checkpoint: Path | None = None) -> dict:
    """What made a run: compared field by field when it is resumed."""
    return plain_json(
        json.loads(
            json.dumps(
                {
                    "command": command,
                    "settings": settings,
                    "sequences": [
                        {"path": str(Path(p).resolve()), "contents_sha1": folder_fingerprint(p)} for p in sequences
                    ],
                    "checkpoint_sha256": _sha256(checkpoint) if checkpoint is not None else None,
                    "leovr_version": __version__,
                },
                default=str,
            )
        )
    )


def differences(old, new, prefix: str = "") -> list[str]:
    """Each leaf where two JSON records differ, as `key.path (folder: old, now: new)`."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            out += differences(old.get(k), new.get(k), f"{prefix}.{k}" if prefix else str(k))
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [d for n, (a, b) in enumerate(zip(old, new)) for d in differences(a, b, f"{prefix}[{n}]")]
    return [] if old == new else [f"{prefix} (folder: {_short(old)}, now: {_short(new)})"]


def _short(v) -> str:
    t = json.dumps(v)
    return t if len(t) <= 60 else t[:57] + "..."


def check_identity(out: Path, identity: dict) -> None:
    """Refuse to resume into `out` unless its run.json names the same run; the message lists every
    difference. A folder without outputs (nothing to resume) passes."""
    out = Path(out)
    path = out / RUN_FILE
    if not path.is_file():
        if out.is_dir() and any(out.iterdir()):
            raise DataError(
                out,
                "holds files but no run.json (not a leovr run, or written by an older "
                "version): resume into a new output folder",
            )
        return
    old = read_json_object(path).get("identity")
    if old is None:
        raise DataError(path, "records no run identity (written by an older leovr): resume into a new output folder")
    diff = differences(plain_json(old), identity)  # folders written before run.json was strict JSON too
    if diff:
        raise DataError(
            out,
            "was written by another run; --resume refused: "
            + brief(diff, 6, "; ")
            + _changed_inputs(out, old, identity),
        )


def _changed_inputs(out: Path, old: dict, new: dict) -> str:
    """Which input files changed since the folder's run started (from its `inputs.json`), when the contents
    of a sequence differ: edited in place, added or removed."""
    try:
        before = json.loads((Path(out) / INPUTS_FILE).read_text())
    except (OSError, ValueError):
        return ""
    lines = []
    for a, b in zip(old.get("sequences") or [], new.get("sequences") or []):
        if isinstance(a, dict) and a != b and isinstance(before.get(b["path"]), dict):
            changed = changed_files(before[b["path"]], file_digests(Path(b["path"])))
            lines += [f"{b['path']}/{c}" for c in changed]
    return f"; input files changed since: {brief(lines, 6, ', ')}" if lines else ""


def write_inputs(out: Path, identity: dict) -> None:
    """`out/inputs.json`: each sequence's files with their content digests, to name the ones a refused resume
    found changed."""
    listing = {s["path"]: file_digests(Path(s["path"])) for s in identity.get("sequences") or []}
    write_text(Path(out) / INPUTS_FILE, json.dumps(listing) + "\n")


def start_run(out: Path, command: str, identity: dict, resume: bool, **extra) -> None:
    """Before any work: check the folder can be written, refuse a resume into a folder another run
    wrote (or an older leovr wrote in millimetres), then record this run in `out/run.json`."""
    check_apart(out, [Path(s["path"]) for s in identity.get("sequences") or []])
    check_output_dir(out)
    if resume:
        check_resumable(out)
        check_identity(out, identity)
    else:
        clear_previous_run(out, command)
    write_run_info(out, command, identity=identity, **extra)
    write_inputs(out, identity)


# what a run writes at the top of its folder (besides folders named depth*): a fresh run into the folder
# removes them first, so that nothing of the earlier run (a frame it had and this one has not) stays
RUN_OUTPUTS = (
    "run.json",
    "inputs.json",
    "metrics.json",
    "timing.json",
    "progress.json",
    "poses_*.txt",
    "landmarks*.npy",
)


def clear_previous_run(out: Path, command: str) -> None:
    """Before a fresh (not resumed) run: refuse a folder holding another command's run, and remove the outputs
    of an earlier run of the same command (its depth maps, poses and metrics; other files stay)."""
    out = Path(out)
    record = read_json_object(out / RUN_FILE) if (out / RUN_FILE).is_file() else None
    if record is None:
        return
    other = record.get("command")
    if other is not None and other != command:
        raise DataError(out, f"holds a `{other}` run; write the `{command}` outputs to another folder")
    for pattern in RUN_OUTPUTS:
        for p in out.glob(pattern):
            p.unlink()
    for p in out.glob("depth*"):
        if p.is_dir():
            shutil.rmtree(p)


def check_apart(out: Path, inputs: list[Path]) -> None:
    """Refuse an output folder that is an input recording or lies inside one: the outputs would become part of
    the recording (a native folder's `depth/` read as its ground truth, its poses overwritten)."""
    where = Path(out).resolve()
    for seq in inputs:
        root = Path(seq).resolve()
        if root.is_dir() and (where == root or root in where.parents):
            raise DataError(out, f"lies inside the input sequence {seq}: write the outputs to a folder outside it")


def check_resumable(out: Path) -> None:
    """A folder with depth PNGs but no run.json was written by an older leovr in millimetres; resuming
    into it would mix two conventions in one folder, so it is refused."""
    out = Path(out)
    if not (out / RUN_FILE).is_file() and any(out.glob("depth*/*.png")):
        raise DataError(
            out, "written by an older leovr (millimetre depth PNGs, no run.json): resume into a new output folder"
        )


@lru_cache(maxsize=8)
def _run_record_at(path: Path, stamp: tuple[int, int]) -> dict:
    return read_json_object(path)


def run_record(run: Path) -> dict | None:
    """A run folder's run.json (None without one), parsed once per version of the file: readers of a
    run's PNGs ask for it per frame."""
    path = (Path(run) / RUN_FILE).resolve()
    if not path.is_file():
        return None
    st = path.stat()
    return _run_record_at(path, (st.st_mtime_ns, st.st_size))


def run_depth_scale(run: Path) -> float:
    """Units per metre of the depth PNGs in an output folder (millimetres for folders without run.json)."""
    record = run_record(run)
    if record is None:
        return LEGACY_DEPTH_SCALE
    path = Path(run) / RUN_FILE
    try:
        scale = float(record["depth_png"]["scale"])
    except (ValueError, KeyError, TypeError) as exc:
        raise DataError(path, f"unreadable run description: {exc}") from exc
    if not np.isfinite(scale) or scale <= 0:
        raise DataError(path, f"depth_png.scale must be a positive number, not {scale}")
    return scale


def png_name(numbers: list[int], index: int) -> str:
    """A frame's output file name: the recording's own frame number (`Sequence.frame_numbers`), so that
    `000042.png` is the drive's frame 42 even when the drive starts later or skips frames."""
    return f"{numbers[index]:06d}.png"


def run_frame_png(run: Path, folder: str, index: int) -> Path:
    """Where a run folder holds frame `index` (position in its sequence): named by the frame number
    recorded in run.json; folders without one (older runs) by position."""
    record = run_record(run)
    numbers = record.get("frame_numbers") if record is not None else None
    if not isinstance(numbers, list) or index >= len(numbers):
        numbers = range(index + 1)
    return Path(run) / folder / png_name(list(numbers), index)


def read_run_depth(run: Path, folder: str, index: int, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Depth (metres) of frame `index` from its PNG in `run/folder`, at the folder's recorded scale
    (with `shape`, a map of another size is refused)."""
    return read_depth_png(run_frame_png(run, folder, index), run_depth_scale(run), shape)
