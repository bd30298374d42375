"""What `leovr batch` runs: sequences from a manifest (YAML or CSV) or every sequence below a folder.

A YAML manifest is a list (or `sequences:` holding a list) of entries, each a path or a mapping
`{path: ..., name: ..., <option>: <value>, ...}`; a CSV manifest has a `path` column, an optional
`name` column, and one column per option (an empty cell leaves the option alone). Options override the
job's config section for that sequence (e.g. `end: 100`, `input: vlp16`). Relative paths are taken from
the manifest's folder. Names (the output sub-folders) default to the folder name and are made unique.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from leovr.data import detect_reader
from leovr.data.io import read_yaml
from leovr.errors import DataError


@dataclass
class BatchItem:
    """One sequence of a batch: its output name, folder and per-sequence options."""

    name: str
    path: Path
    options: dict[str, Any] = field(default_factory=dict)


def discover(root: Path) -> list[Path]:
    """Every folder at or below `root` whose layout is a sequence's (not looking inside a sequence), and every
    ROS 1 bag file."""
    found = []
    for here, dirs, files in os.walk(root):
        p = Path(here)
        if detect_reader(p, search=False) is not None:
            found.append(p)
            dirs.clear()
        else:
            dirs.sort()
            found += [p / f for f in sorted(files) if f.endswith(".bag")]
    return found


def _entry(raw: Any, base: Path, where: str) -> BatchItem:
    if isinstance(raw, str):
        raw = {"path": raw}
    if not isinstance(raw, dict) or not raw.get("path"):
        raise DataError(where, f"each entry needs a path, got {raw!r}")
    opts = {k: v for k, v in raw.items() if k not in ("path", "name") and v is not None and v != ""}
    path = Path(str(raw["path"])).expanduser()
    path = path if path.is_absolute() else base / path
    name = str(raw.get("name") or "")
    if name and (name in (".", "..") or "/" in name or "\\" in name):
        raise DataError(where, f"name {name!r} must be a plain folder name (the sequence's output folder under --out)")
    return BatchItem(name, path, opts)


def _read_yaml(path: Path) -> list[BatchItem]:
    doc = read_yaml(path)
    if isinstance(doc, dict):
        doc = doc.get("sequences")
    if not isinstance(doc, list):
        raise DataError(path, "a manifest is a list of sequences (or `sequences:` holding one)")
    return [_entry(raw, path.parent, f"{path} entry {n + 1}") for n, raw in enumerate(doc)]


def _read_csv(path: Path) -> list[BatchItem]:
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, csv.Error, UnicodeDecodeError) as exc:
        raise DataError(path, f"cannot read this manifest: {exc}") from exc
    if rows and "path" not in rows[0]:
        raise DataError(path, "a CSV manifest needs a `path` column")
    items = []
    for n, row in enumerate(rows):
        if None in row:  # csv puts cells beyond the header under None
            raise DataError(path, f"row {n + 2} has {len(row[None])} more cell(s) than the header's columns")
        try:
            parsed = {k: (yaml.safe_load(v) if k not in ("path", "name") and v else v) for k, v in row.items() if k}
        except yaml.YAMLError as exc:
            raise DataError(path, f"row {n + 2}: a cell is not a value ({str(exc).splitlines()[0]})") from exc
        items.append(_entry(parsed, path.parent, f"{path} row {n + 2}"))
    return items


def read_batch(source: Path) -> list[BatchItem]:
    """The batch a manifest file or a folder names, with unique output names."""
    source = Path(source)
    if source.is_dir():
        if detect_reader(source, search=False) is not None:
            items = [BatchItem("", source)]
        else:
            items = [BatchItem("", p) for p in discover(source)]
        if not items:
            raise DataError(source, "no sequence found below this folder (native, TUM RGB-D, KITTI odometry or raw)")
    elif source.suffix.lower() in (".yaml", ".yml"):
        items = _read_yaml(source)
    elif source.suffix.lower() == ".csv":
        items = _read_csv(source)
    elif not source.exists():
        raise DataError(source, "no such manifest or folder")
    else:
        raise DataError(source, "a batch is a folder of sequences or a .yaml / .yml / .csv manifest")
    if not items:
        raise DataError(source, "the manifest lists no sequence")
    seen: dict[str, int] = {}
    for it in items:
        base = it.name or (it.path.stem if it.path.is_file() else it.path.name) or "sequence"
        n = seen.get(base, 0)
        seen[base] = n + 1
        it.name = base if n == 0 else f"{base}_{n + 1}"
    return items
