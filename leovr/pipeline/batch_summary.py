"""A batch's summary: one row per sequence (status, error, frames, per-stage time, depth and trajectory
metrics where there is ground truth) as `summary.csv` and `summary.md`, and MAE per sequence as a plot."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from leovr.data.io import atomic_write, read_json_object, write_text
from leovr.errors import DataError

COLUMNS = (
    "name",
    "status",
    "frames",
    "attempts",
    "wall_s",
    "generator_ms",
    "frontend_ms",
    "graph_ms",
    "output_ms",
    "mae_nearest_m",
    "mae_ipbasic_m",
    "mae_generator_m",
    "mae_refined_m",
    "mae_m",
    "ate_m",
    "error",
    "path",
)
METHODS = ("nearest", "ipbasic", "generator", "refined")


def read_json_or_empty(path: Path) -> dict:
    """A JSON object file, or {} when it is missing or unreadable (a sequence that never got that far)."""
    try:
        return read_json_object(path) if path.is_file() else {}
    except DataError:
        return {}


def summary_row(out: Path, state: dict) -> dict:
    """A state record of `run_sequence` with the figures of the sequence's metrics.json."""
    row = {k: state.get(k, "") for k in COLUMNS}
    m = (
        read_json_or_empty(out / str(state.get("name", "")) / "metrics.json")
        if state.get("status") in ("done", "skipped")
        else {}
    )
    row["frames"] = m.get("frames", "")
    for stage in ("generator_ms", "frontend_ms", "graph_ms", "output_ms"):
        v = m.get("timing", {}).get(stage)
        row[stage] = round(v, 1) if isinstance(v, (int, float)) else ""
    for method in METHODS:
        v = m.get("depth", {}).get(method, {}).get("mae_m")
        row[f"mae_{method}_m"] = round(v, 4) if v is not None else ""
    if m.get("mae_m") is not None:  # a `complete` job: one method
        row["mae_m"] = round(m["mae_m"], 4)
    ate = m.get("trajectory", {}).get("leovr", {}).get("ate_m")
    row["ate_m"] = round(ate, 4) if ate is not None else ""
    return row


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _markdown(rows: list[dict]) -> str:
    counts = {s: sum(r["status"] == s for r in rows) for s in ("done", "skipped", "failed", "pending", "running")}
    head = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
    cols = [c for c in COLUMNS if c != "path" and any(r[c] not in ("", None) for r in rows)]
    lines = [
        f"# Batch summary ({len(rows)} sequences: {head})",
        "",
        "| " + " | ".join(cols) + " |",
        "|" + "---|" * len(cols),
    ]
    lines += ["| " + " | ".join(str(r[c]).replace("|", "/") for c in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = [
        k
        for k in ("mae_nearest_m", "mae_ipbasic_m", "mae_generator_m", "mae_refined_m", "mae_m")
        if any(r[k] != "" for r in rows)
    ]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.9 * len(rows) + 2), 3.2))
    x = np.arange(len(rows))
    width = 0.8 / max(len(keys), 1)
    for n, k in enumerate(keys):
        ax.bar(x + n * width, [float(r[k]) if r[k] != "" else np.nan for r in rows], width, label=k[4:-2] or "mae")
    ax.set_xticks(x + 0.4 - width / 2, [r["name"] for r in rows], rotation=30, ha="right")
    ax.set_ylabel("depth MAE (m)")
    ax.set_title("MAE per sequence (failed / unscored: no bar)")
    if keys:
        ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))
    plt.close(fig)


def write_summary(out: Path, states: list[dict], plot: bool = True) -> list[dict]:
    """summary.csv and summary.md (and mae_per_sequence.png) in `out`; returns the rows."""
    rows = [summary_row(out, s) for s in states]
    write_text(out / "summary.csv", _csv(rows))
    write_text(out / "summary.md", _markdown(rows))
    if plot:
        _plot(out / "mae_per_sequence.png", rows)
    return rows
