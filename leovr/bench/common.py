"""Shared benchmark plumbing: the metric keys every depth benchmark reports, and the JSON envelope."""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

from leovr import __version__
from leovr.data.io import write_text

DEPTH_KEYS = ("mae_m", "rmse_m", "absrel", "delta1", "imae_per_km", "irmse_per_km", "p95_m", "n", "ms_per_frame")


def depth_entry(metrics: dict) -> dict:
    """The benchmark contract's per-method record: headline keys plus per-bin metrics."""
    entry = {k: metrics.get(k) for k in DEPTH_KEYS}
    entry["bins"] = {b: {k: v.get(k) for k in ("mae_m", "rmse_m", "absrel", "delta1", "n")} for b, v in metrics["bins"].items()}
    return entry


def write_bench(out: Path, name: str, body: dict, started: float, argv: list[str] | None = None) -> dict:
    """Wrap results with provenance (command, machine, duration) and write them atomically."""
    doc = {
        "benchmark": name,
        "leovr_version": __version__,
        "command": " ".join(argv if argv is not None else sys.argv),
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "processor": platform.processor()},
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "duration_s": round(time.time() - started, 2),
        **body,
    }
    write_text(Path(out), json.dumps(doc, indent=2) + "\n")
    return doc
