"""Shared benchmark plumbing: the metric keys every depth benchmark reports, and the JSON envelope."""

from __future__ import annotations

import json
import platform
import subprocess
import sys
import time
from pathlib import Path

from leovr import __version__
from leovr.data.io import write_text

DEPTH_KEYS = ("mae_m", "rmse_m", "absrel", "delta1", "imae_per_km", "irmse_per_km", "p95_m", "n", "ms_per_frame")


def depth_entry(metrics: dict) -> dict:
    """The benchmark contract's per-method record: headline keys plus per-bin metrics."""
    entry = {k: metrics.get(k) for k in DEPTH_KEYS}
    entry["bins"] = {
        b: {k: v.get(k) for k in ("mae_m", "rmse_m", "absrel", "delta1", "n")} for b, v in metrics["bins"].items()
    }
    return entry


def _git(repo: Path, *args: str) -> str:
    """Stdout of `git ARGS` run in `repo`; raises when git is missing or fails."""
    done = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, timeout=10, check=True)
    return done.stdout.strip()


def git_commit() -> str | None:
    """Short hash of the checkout holding this package, "-dirty" if it has changes; None without git."""
    repo = Path(__file__).resolve().parent
    try:
        head = _git(repo, "rev-parse", "--short", "HEAD")
        return (head + ("-dirty" if _git(repo, "status", "--porcelain") else "")) if head else None
    except (OSError, subprocess.SubprocessError):
        return None


def command_line(argv: list[str]) -> str:
    """The command as a user types it: the CLI named `leovr` however it was started (its entry point, its
    script, `python -m leovr.cli`, `python -c "from leovr.cli import main; main()"`)."""
    cli = bool(argv) and (Path(argv[0]).name in ("leovr", "cli.py") or argv[0] == "-c")
    return " ".join((["leovr"] if cli else argv[:1]) + argv[1:])


def write_bench(out: Path, name: str, body: dict, started: float, argv: list[str] | None = None) -> dict:
    """Wrap results with provenance (command, machine, duration) and write them atomically."""
    doc = {
        "benchmark": name,
        "leovr_version": __version__,
        "command": command_line(argv if argv is not None else sys.argv),
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "processor": platform.processor(),
        },
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "commit": git_commit(),
        "duration_s": round(time.time() - started, 2),
        **body,
    }
    write_text(Path(out), json.dumps(doc, indent=2) + "\n")
    return doc
