"""`leovr train` and `leovr batch`: the long jobs of the command line (leovr.cli registers them in
its order); a thin layer over the library like the rest of it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from leovr.cli_bench import ConfigOpt
from leovr.config import load_config, override


def train(
    sequences: Optional[list[Path]] = typer.Argument(None, help="Raw sequence folders (--mode selfsup)."),
    out: Path = typer.Option(..., "--out", "-o", help="Run folder (checkpoints, log.jsonl / log.csv)."),
    mode: str = typer.Option(
        "supervised", help="supervised (simulator ground truth) | selfsup (raw sequences, no ground truth)."
    ),
    config: Optional[Path] = ConfigOpt,
    dataset: Optional[Path] = typer.Option(None, help="Dataset folder with manifest.json (--mode supervised)."),
    epochs: Optional[int] = typer.Option(None),
    batch_size: Optional[int] = typer.Option(None, "--batch-size"),
    max_frames: Optional[int] = typer.Option(
        None, "--max-frames", min=1, help="Cap on training frames (selfsup: per sequence)."
    ),
    init_checkpoint: Optional[Path] = typer.Option(None, "--init-checkpoint", help="Start from these weights."),
    rerun: Optional[Path] = typer.Option(
        None, help="selfsup: log flow masks, warped images and photometric error to this .rrd."
    ),
    resume: bool = typer.Option(False, help="Continue from OUT/checkpoint_last.pt."),
) -> None:
    """Train the depth generator: supervised on simulator splits, or self-supervised (LeoVR Sec. IV) on
    raw camera + LiDAR sequences with poses from the graph. Scales over processes with torchrun."""
    init = None if init_checkpoint is None else str(init_checkpoint)
    if mode == "selfsup":
        from selfsup.trainer import train_selfsup

        if not sequences:
            raise typer.BadParameter("give at least one sequence folder", param_hint="SEQUENCES")
        cfg = override(
            load_config(config).selfsup,
            epochs=epochs,
            batch_size=batch_size,
            max_frames=max_frames,
            init_checkpoint=init,
        )
        from leovr.pipeline.refine import run_refine

        r = train_selfsup(cfg, list(sequences), out, run_refine, resume=resume, rerun=rerun)
        if r:
            typer.echo(
                f"epoch {r['epoch']} ({r['stage']}): loss {r['loss']:.4f}, photometric {r['photometric']:.4f}, "
                f"masks keep {100 * r['mask_kept']:.0f}% -> {out}/generator.pt"
            )
        elif resume:
            typer.echo(f"nothing to train: {out} already holds {cfg.epochs} epoch(s); give more with --epochs")
        return
    if mode != "supervised":
        raise typer.BadParameter("--mode is supervised or selfsup", param_hint="--mode")
    if sequences:
        raise typer.BadParameter(
            "--mode supervised reads the simulator dataset (--dataset), not sequence folders", param_hint="SEQUENCES"
        )
    from leovr.depth.train import train_supervised

    cfg = override(
        load_config(config).train,
        dataset=None if dataset is None else str(Path(dataset).resolve()),  # absolute: resumable from elsewhere
        epochs=epochs,
        batch_size=batch_size,
        max_frames=max_frames,
        init_checkpoint=init,
    )
    r = train_supervised(cfg, out, resume=resume)
    typer.echo(f"epoch {r.get('epoch')}: val MAE {r.get('val_mae_m', float('nan')):.3f} m -> {out}")


def batch(
    source: Path = typer.Argument(..., help="A folder of sequences, or a manifest (.yaml / .csv) listing them."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder: <name>/ per sequence, summary.csv / .md."),
    job: Optional[str] = typer.Option(None, "--job", help="refine (default) | complete"),
    address: Optional[str] = typer.Option(
        None, "--address", help="Ray cluster to join (auto | HOST:PORT); default: a local instance."
    ),
    workers: Optional[int] = typer.Option(
        None, "--workers", help="Sequences in flight (default: CPUs / cpus_per_task)."
    ),
    fuse_map: Optional[bool] = typer.Option(
        None, "--map/--no-map", help="Refine jobs: also fuse each run into <name>/map."
    ),
    config: Optional[Path] = ConfigOpt,
) -> None:
    """Many sequences, one Ray task each: outputs as `leovr refine` writes them, a summary, and a re-run
    that skips finished sequences and resumes interrupted ones."""
    from leovr.pipeline.batch import run_batch
    from leovr.pipeline.batch_manifest import read_batch

    cfg = load_config(config)
    cfg.batch = override(cfg.batch, job=job, address=address, workers=workers, map=fuse_map)
    rows = run_batch(read_batch(source), cfg, out)
    counts = {s: sum(r["status"] == s for r in rows) for s in ("done", "skipped", "failed")}
    typer.echo(", ".join(f"{n} {s}" for s, n in counts.items()) + f" -> {out / 'summary.md'}")
    for r in rows:
        if r["status"] == "failed":
            typer.echo(f"failed: {r['name']}: {r.get('error', '')}")
    if counts["failed"]:
        raise typer.Exit(1)
