"""`leovr demo`: the README's main job. By default it renders a short Mid-40 sequence of the
procedural city (the embedded default), completes its depth with the classical methods, scores them
against the dense ground truth and writes a Markdown report. With `data`, it runs on a recorded
sequence instead (a cheap input simulated from its dense scan, scored on held-out points)."""

from __future__ import annotations

import json
from pathlib import Path

from leovr.config import CompleteConfig, DemoConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.paths import shipped_checkpoint
from leovr.pipeline.completion import run_completion
from leovr.sim.simulate import simulate

CLASSICAL = ("nearest", "ipbasic")


def demo_methods() -> tuple[str, ...]:
    """The classical methods, plus the learned generator when its checkpoint ships with the package."""
    return CLASSICAL + (("generator",) if shipped_checkpoint().is_file() else ())


def _fmt(v: float | None, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def run_demo(out: Path, cfg: DemoConfig, progress: bool = True) -> dict:
    """Complete `cfg.frames` frames with each method; write metrics.json and report.md."""
    out = Path(out)
    if cfg.data:
        seq = open_sequence(cfg.data)
        inp = cfg.input or "mid40"
        source = f"recorded sequence `{seq.path}` ({seq.name})"
    else:
        sim = SimulateConfig(scenario=cfg.scenario, lidar=cfg.lidar, frames=cfg.frames, seed=cfg.seed)
        simulate(sim, out / "sequence", preview=True, progress=progress)
        seq = open_sequence(out / "sequence")
        inp = cfg.input or "full"
        source = (f"generated `{cfg.scenario}` sequence, {cfg.lidar} LiDAR, seed {cfg.seed} "
                  f"(`{out / 'sequence'}`, preview in `sequence/preview.png`)")
    results = {}
    for method in demo_methods():
        ccfg = CompleteConfig(method=method, input=inp, end=cfg.frames)
        results[method] = run_completion(seq, ccfg, out / method, progress=progress)
    write_text(out / "metrics.json", json.dumps(results, indent=2) + "\n")
    first = next(iter(results.values()))
    bins = list(first["bins"])
    lines = [
        "# leovr demo: depth completion report",
        "",
        f"Input: {source}; frames 0-{first['frames'] - 1}; LiDAR input `{inp}`.",
        f"Ground truth: {first['ground_truth']}.",
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
