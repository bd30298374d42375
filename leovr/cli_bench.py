"""`leovr bench ...`: each benchmark writes its JSON and prints the tables docs/benchmarks.md shows for it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from leovr.bench.config import load_bench_config
from leovr.config import override

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks writing JSON results (see docs/benchmarks.md).")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config file (see configs/default.yaml).")
BenchConfigOpt = typer.Option(
    None, "--config", "-c", help="YAML file of benchmark settings (see configs/bench.yaml, docs/bench_config.md)."
)
OutOpt = typer.Option(..., "--out", "-o", help="JSON results file.")


@bench_app.command("baseline")
def bench_baseline(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="Every 6th frame only (under 2 minutes)."),
    data: Optional[Path] = typer.Option(None, help="KITTI raw clip (default: ../shared/data/kitti_raw)."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Nearest and IP-Basic completion on the KITTI raw clip with VLP-16 and Mid-40 inputs."""
    from leovr.bench.baseline import run_baseline_bench
    from leovr.paths import kitti_raw_dir

    cfg = override(load_bench_config(config).baseline, data=None if data is None else str(data))
    doc = run_baseline_bench(Path(cfg.data) if cfg.data else kitti_raw_dir(), out, cfg, quick)
    _print_bench("baseline", doc, out)


@bench_app.command("depth")
def bench_depth(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="A 4-frame rendered test set and every 6th KITTI frame."),
    config: Optional[Path] = BenchConfigOpt,
    checkpoint: Optional[Path] = typer.Option(None, help="Generator weights (default: the shipped checkpoint)."),
) -> None:
    """Nearest, IP-Basic and the generator on simulator test sequences and the KITTI raw clip."""
    from leovr.bench.depth import run_depth_bench

    cfg = override(load_bench_config(config).depth, checkpoint=None if checkpoint is None else str(checkpoint))
    doc = run_depth_bench(out, cfg, quick)
    _print_bench("depth", doc, out)


@bench_app.command("refine")
def bench_refine(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="8-frame rendered test sequences and 8 KITTI frames."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Depth (IP-Basic, generator, refined), trajectories (KISS-ICP, LeoVR), timing and window ablation."""
    from leovr.bench.refine import run_refine_bench

    doc = run_refine_bench(out, load_bench_config(config).refine, quick)
    _print_bench("refine", doc, out)


@bench_app.command("loop")
def bench_loop(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="One LiDAR, one city loop."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Loop closure: ATE with and without, true / false / missed loops, query time."""
    from leovr.bench.loop import run_loop_bench

    doc = run_loop_bench(out, load_bench_config(config).loop, quick)
    _print_bench("loop", doc, out)


@bench_app.command("speed")
def bench_speed(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="12 rendered and 12 KITTI frames."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Time per frame of refine per stage (median / p95 / max), frames per second, the graph's growth
    along a 200-frame drive, with the same run's MAE / ATE and IP-Basic's time as the yard stick."""
    from leovr.bench.speed import run_speed_bench

    doc = run_speed_bench(out, load_bench_config(config).speed, quick)
    _print_bench("speed", doc, out)


@bench_app.command("batch")
def bench_batch(
    out: Path = typer.Option(..., "--out", "-o", help="JSON results file (runs in <stem>_work/)."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Wall time of `leovr batch` with 1 and 2 workers on the same generated sequences."""
    from leovr.bench.batch import run_batch_bench

    doc = run_batch_bench(out, load_bench_config(config).batch)
    _print_bench("batch", doc, out)


@bench_app.command("real")
def bench_real(
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="JSON results file (runs kept in <stem>_work/, resumed with the same settings and commit).",
    ),
    quick: bool = typer.Option(False, help="First 12 frames of each clip."),
    clips: Optional[str] = typer.Option(
        None, help="Comma-separated KITTI raw drives (default: every one under ../shared/data)."
    ),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Real KITTI raw drives: nearest, IP-Basic, prior, shipped generator / refined on the same held-out pixels;
    leovr's ATE against KISS-ICP's where a drive has poses."""
    from leovr.bench.real import run_real_bench

    cfg = load_bench_config(config).real
    cfg = override(cfg, clips=[c.strip() for c in clips.split(",")] if clips else None)
    doc = run_real_bench(out, cfg, quick=quick)
    _print_bench("real", doc, out)


@bench_app.command("map")
def bench_map(
    out: Path = OutOpt,
    quick: bool = typer.Option(False, help="The first frames of each clip only."),
    clips: Optional[str] = typer.Option(
        None, help="Comma-separated KITTI raw drives (default: every one under ../shared/data)."
    ),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Maps of each real drive from the refined depth, the nearest fill and the accumulated cheap returns, scored
    on the held-out returns (accuracy, completeness)."""
    from leovr.bench.map import run_map_bench

    cfg = override(load_bench_config(config).map, clips=[c.strip() for c in clips.split(",")] if clips else None)
    doc = run_map_bench(out, cfg, quick=quick)
    _print_bench("map", doc, out)


@bench_app.command("selfsup")
def bench_selfsup(
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="JSON results file (runs kept in <stem>_work/, resumed with the same settings and commit).",
    ),
    quick: bool = typer.Option(False, help="One short sequence per scenario, two epochs."),
    parts: Optional[str] = typer.Option(
        None, help="Comma-separated parts to run: synthetic,traffic,kitti (default: all)."
    ),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Cold-start self-supervised training vs untrained, no-mask, no-L_f/L_r and supervised models."""
    from leovr.bench.selfsup import run_selfsup_bench

    cfg = override(load_bench_config(config).selfsup, parts=[p.strip() for p in parts.split(",")] if parts else None)
    doc = run_selfsup_bench(out, cfg, quick)
    _print_bench("selfsup", doc, out)


@bench_app.command("simulate")
def bench_simulate(
    out: Path = OutOpt,
    frames: Optional[int] = typer.Option(None, help="Frames per LiDAR model."),
    config: Optional[Path] = BenchConfigOpt,
) -> None:
    """Rendering speed (frames per second) at 448x256 for each LiDAR model."""
    from leovr.bench.simulate import run_simulate_bench

    doc = run_simulate_bench(out, override(load_bench_config(config).simulate, frames=frames))
    _print_bench("simulate", doc, out)


def _print_bench(name: str, doc: dict, out: Path) -> None:
    """A bench's tables as docs/benchmarks.md shows them, and where the JSON went."""
    from leovr.bench.report import section

    typer.echo(section(name, doc))
    typer.echo(f"-> {out}")
