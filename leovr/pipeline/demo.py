"""`leovr demo`: the README's main job. For now: classical completion of a cheap LiDAR input on
a short stretch of the shared KITTI raw clip, with a Markdown report."""

from __future__ import annotations

import json
from pathlib import Path

from leovr.config import CompleteConfig, DemoConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.paths import kitti_raw_dir
from leovr.pipeline.completion import run_completion

METHODS = ("nearest", "ipbasic")


def _fmt(v: float | None, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def run_demo(out: Path, cfg: DemoConfig, progress: bool = True) -> dict:
    """Complete the first `cfg.frames` frames with each classical method; write metrics and a report."""
    seq = open_sequence(Path(cfg.data) if cfg.data else kitti_raw_dir())
    results = {}
    for method in METHODS:
        ccfg = CompleteConfig(method=method, input=cfg.input, end=cfg.frames)
        results[method] = run_completion(seq, ccfg, out / method, progress=progress)
    write_text(out / "metrics.json", json.dumps(results, indent=2) + "\n")
    bins = list(next(iter(results.values()))["bins"])
    lines = [
        "# leovr demo: depth completion report",
        "",
        f"Sequence: `{seq.path}` ({seq.name}), frames 0-{cfg.frames - 1}, cheap input `{cfg.input}`.",
        f"Ground truth: {next(iter(results.values()))['ground_truth']}.",
        "",
        "| method | MAE (m) | RMSE (m) | AbsRel | delta<1.25 | ms/frame | " + " | ".join(f"MAE {b} m" for b in bins) + " |",
        "|---" * (6 + len(bins)) + "|",
    ]
    for method, m in results.items():
        per_bin = " | ".join(_fmt(m["bins"][b].get("mae_m")) for b in bins)
        lines.append(
            f"| {method} | {_fmt(m['mae_m'])} | {_fmt(m['rmse_m'])} | {_fmt(m['absrel'])} | "
            f"{_fmt(m['delta1'])} | {_fmt(m['ms_per_frame'], 1)} | {per_bin} |"
        )
    lines += ["", "Depth maps: `<method>/depth/NNNNNN.png` (uint16, millimetres).", ""]
    write_text(out / "report.md", "\n".join(lines))
    return results
