"""`run.json`: what a leovr output folder holds, so that its files are read back as they were written.

Today it records the depth PNG convention (units per metre). Output folders written before it
existed have no `run.json`; their depth PNGs were millimetres, and they are read as such.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from leovr import __version__
from leovr.data.io import DEPTH_SCALE, LEGACY_DEPTH_SCALE, read_depth_png, write_text
from leovr.errors import DataError

RUN_FILE = "run.json"


def depth_png_record(scale: float = DEPTH_SCALE) -> dict:
    return {"scale": scale, "unit": f"uint16 = metres x {scale:g}, 0 = unknown",
            "max_m": round(65535.0 / scale, 3)}


def write_run_info(out: Path, command: str, **extra) -> None:
    """Write `out/run.json` (the command, leovr's version, the depth PNG convention and `extra`)."""
    body = {"command": command, "leovr_version": __version__, "depth_png": depth_png_record(), **extra}
    write_text(Path(out) / RUN_FILE, json.dumps(body, indent=2) + "\n")


def check_resumable(out: Path) -> None:
    """A folder with depth PNGs but no run.json was written by an older leovr in millimetres; resuming
    into it would mix two conventions in one folder, so it is refused."""
    out = Path(out)
    if not (out / RUN_FILE).is_file() and any(out.glob("depth*/*.png")):
        raise DataError(out, "written by an older leovr (millimetre depth PNGs, no run.json): "
                             "resume into a new output folder")


def run_depth_scale(run: Path) -> float:
    """Units per metre of the depth PNGs in an output folder (millimetres for folders without run.json)."""
    path = Path(run) / RUN_FILE
    if not path.is_file():
        return LEGACY_DEPTH_SCALE
    try:
        scale = float(json.loads(path.read_text())["depth_png"]["scale"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(path, f"unreadable run description: {exc}") from exc
    if not np.isfinite(scale) or scale <= 0:
        raise DataError(path, f"depth_png.scale must be a positive number, not {scale}")
    return scale


def read_run_depth(run: Path, folder: str, index: int) -> np.ndarray:
    """Depth (metres) of frame `index` from `run/folder/NNNNNN.png`, at the folder's recorded scale."""
    return read_depth_png(Path(run) / folder / f"{index:06d}.png", run_depth_scale(run))
