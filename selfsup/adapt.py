"""`leovr adapt`: fine-tune the generator on the user's own recordings, without any ground truth.

Starting from the shipped generator (or `--init`), each training frame's own LiDAR input is split
into a thinner input and hidden returns (selfsup.masked_lidar); the network runs on the thinner input
at its training focal length, exactly as at inference (its input prior read from the full-resolution
prior: leovr.depth.inference.network_priors) its residual, fusion weight and sigma are
resized to the full frame and combined with the full-resolution prior, and the loss is read at the
hidden returns: L1 on depth, the Gaussian NLL of the uncertainty head (all-day eq. 2, on detached
depth, so the graph's prior is trained on the user's data too), and a small edge-aware smoothness.
Frames held out of training (every `val_every`-th) validate on the same task with fixed splits of
their input; training stops when that stops improving and the best epoch is kept.

Data-parallel: started by `torchrun --nproc-per-node N` or Ray Train's `TorchTrainer` (`leovr batch
--job adapt+refine`), every process prepares the same frames, trains on its share of each epoch's
shuffled splits (DistributedDataParallel, gloo: its share of every batch of `batch_size`, so that the
steps are those of one process) and validates on
its share of the validation frames; the sums are added over processes so that every process takes the
same early-stopping decision. Process 0 writes the files.

After training, the best epoch's weights get a blend (GeneratorConfig.blend): the weight of their log
depth against their prior's, the one of 1, 0.75, ..., 0 with the lowest MAE at the validation frames'
hidden returns. Where the network does not beat its prior on the user's data, the prior carries more.

The int8 runtime's calibration table (leovr.depth.quantize) is measured last, on every frame's whole input.

Outputs in OUT: `generator.pt` (best validation, with its blend and int8 table; `leovr refine/complete --checkpoint`
take it),
`checkpoint_last.pt` (resume), `log.jsonl`, `run.json`. Only the cheap input is read: never held-out
evaluation points, ground-truth depth or poses.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from leovr.config import AdaptConfig
from leovr.data.io import check_output_dir, write_text
from leovr.data.run_info import run_identity, start_run
from leovr.data.sequence import Sequence
from leovr.depth.inference import load_generator
from leovr.depth.network import DepthGenerator, blend_log_depth
from leovr.depth.runtime import calibrate_generator
from leovr.depth.train import read_resume_state, save_checkpoint
from leovr.errors import DataError
from leovr.threads import single_threaded_blas
from selfsup.adapt_data import AdaptFrame, input_frames, network_feeds
from selfsup.adapt_loss import StepLoss, at_hidden, batch_loss, batches, forward_parts, set_teachers, share
from selfsup.distributed import all_max, all_sum, barrier, distributed, raise_shared


@torch.no_grad()
def validate(model: DepthGenerator, frames: list[AdaptFrame], rank: int = 0, world: int = 1) -> float:
    """MAE (metres) at the hidden returns of every split of the validation frames (fixed splits); with
    several processes each takes every `world`-th frame and the sums are added over all of them."""
    model.eval()
    total, n = 0.0, 0
    for b in batches([(fr, s) for fr in frames[rank::world] for s in fr.splits], 4):
        _, e, c = batch_loss(model, b, 0.0, 0.0)
        total, n = total + e, n + c
    total, n = all_sum([total, n], world)
    return total / max(n, 1)


BLENDS = (1.0, 0.75, 0.5, 0.25, 0.0)  # network weights tried by choose_blend (first = preferred on a tie)


@torch.no_grad()
def choose_blend(
    model: DepthGenerator, frames: list[AdaptFrame], rank: int = 0, world: int = 1
) -> tuple[float, dict[float, float]]:
    """The weight of the network's log depth against its prior's (GeneratorConfig.blend) with the lowest
    MAE at the validation frames' hidden returns, and the MAE of each weight in BLENDS. The masked
    task ranks them as the held-out beams do: on the KITTI clip's development frames it picks the prior
    alone for VLP-16-like input and 0.75 for Mid-40-like, the best weights there."""
    model.eval()
    chosen = model.cfg
    model.cfg = replace(chosen, blend=1.0)
    sums, n = [0.0] * len(BLENDS), 0
    try:
        for b in batches([(fr, s) for fr in frames[rank::world] for s in fr.splits], 4):
            parts = forward_parts(
                model,
                torch.stack([fr.image for fr, _ in b]),
                torch.stack([s.sparse for _, s in b]),
                torch.stack([s.prior for _, s in b]),
            )
            for k, (_, s) in enumerate(b):
                if len(s.target):
                    net = at_hidden(model, parts, k, s)[1]
                    for j, w in enumerate(BLENDS):
                        sums[j] += float((blend_log_depth(net, s.prior_at, w) - s.target).abs().sum())
                    n += len(s.target)
    finally:
        model.cfg = chosen
    *sums, n = all_sum([*sums, n], world)
    mae = {w: e / max(n, 1) for w, e in zip(BLENDS, sums)}
    return (min(BLENDS, key=lambda w: (mae[w], BLENDS.index(w))) if n else 1.0), mae


@single_threaded_blas
def adapt(seqs: list[Sequence], cfg: AdaptConfig, out: Path, resume: bool = False, progress: bool = True) -> dict:
    """Adapt the generator to `seqs`; returns the last log record (with the best validation MAE)."""
    from leovr.paths import shipped_checkpoint

    out = Path(out)
    rank, world = distributed()
    init = Path(cfg.init_checkpoint) if cfg.init_checkpoint else shipped_checkpoint()
    model = load_generator(init)
    if not model.uses_prior:
        raise DataError(init, "adaptation needs a residual-mode generator (network output residual or fusion)")
    model.cfg = replace(model.cfg, blend=1.0)  # train the network itself; its blend is chosen after training
    model.sigma_on_detached = True  # the uncertainty head learns from its NLL, which never reaches the depth path
    last = out / "checkpoint_last.pt"
    settings = cfg.model_dump(exclude={"epochs", "patience", "max_minutes"})  # may change on resume
    # read before anything is written: a missing or truncated checkpoint is refused, never started again from scratch
    keys = ("model", "optimizer", "epoch", "best_val_mae_m", "since_best", "minutes")
    state = read_resume_state(last, keys) if resume else None
    start_adapt_run(out, cfg, seqs, init, resume, settings, rank, world)
    torch.manual_seed(cfg.seed)
    lead = rank == 0
    frames = input_frames(seqs, cfg, progress and lead)
    is_val = [bool(cfg.val_every) and j % cfg.val_every == cfg.val_every // 2 for j in range(len(frames))]
    val = [fr for fr, v in zip(frames, is_val) if v]
    train = [fr for fr, v in zip(frames, is_val) if not v] or frames
    if cfg.weight_anchor > 0:
        set_teachers(model, train)  # before any weight moves (on resume: from the starting network too)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    start, best, since_best, minutes = 0, float("inf"), 0, 0.0
    log_path = out / "log.jsonl"
    if state is not None:
        start, best, since_best, minutes = restored(state, model, opt, last)
    else:
        best = validate(model, val, rank, world) if val else float("inf")
        if lead:
            log_path.unlink(missing_ok=True)
            save_best(model, out, cfg, init, seqs, 0, best)
            with open(log_path, "a") as fh:
                fh.write(
                    json.dumps({"epoch": 0, "val_mae_m": finite(best), "note": "before adaptation", "processes": world})
                    + "\n"
                )
    step = StepLoss(model, cfg)
    if world > 1:  # BatchNorm is frozen (below): no buffers to sync per step; without the NLL the sigma head is unused
        step = torch.nn.parallel.DistributedDataParallel(
            step, forward_sync_buffers=False, find_unused_parameters=cfg.weight_nll == 0
        )
    gen = torch.Generator().manual_seed(cfg.seed)
    record: dict = {"epoch": start, "best_val_mae_m": finite(best)}
    for epoch in range(start, cfg.epochs):
        if since_best >= cfg.patience or (cfg.max_minutes and minutes >= cfg.max_minutes):
            break
        t0 = time.time()
        loss_sum, n_loss, err, cnt = train_epoch(
            model, step, opt, train, cfg, epoch, gen, rank, world, progress and lead
        )
        val_mae = validate(model, val, rank, world) if val else float("nan")
        minutes = all_max(minutes + (time.time() - t0) / 60.0, world)
        improved = not val or val_mae < best
        since_best = 0 if improved else since_best + 1
        if improved:
            best = val_mae if val else best
            if lead:
                save_best(model, out, cfg, init, seqs, epoch + 1, val_mae)
        record = {
            "epoch": epoch + 1,
            "train_loss": loss_sum / max(n_loss, 1),
            "train_mae_m": err / max(cnt, 1),
            "val_mae_m": finite(val_mae),
            "best_val_mae_m": finite(best),
            "minutes": round(minutes, 2),
            "processes": world,
        }
        if lead:
            with open(log_path, "a") as fh:
                fh.write(json.dumps(record) + "\n")
            save_checkpoint(
                last,
                {
                    "model": model.state_dict(),
                    "optimizer": opt.state_dict(),
                    "epoch": epoch,
                    "best_val_mae_m": best,
                    "since_best": since_best,
                    "minutes": minutes,
                    "settings": settings,
                    "sequences": [str(s.path) for s in seqs],
                    "network": model.cfg.__dict__,
                },
            )
    record.update({"frames_train": len(train), "frames_val": len(val), "minutes": round(minutes, 2)})
    finish(model, frames, val, record, out, cfg, init, seqs, rank, world)
    return record


def start_adapt_run(
    out: Path, cfg: AdaptConfig, seqs: list[Sequence], init: Path, resume: bool, settings: dict, rank: int, world: int
) -> None:
    """Process 0 checks the output folder, then the selection, then records the run (run.json); an error stops
    every process, not only process 0, and nothing is written before the checks pass."""
    error = None
    if rank == 0:
        try:
            check_output_dir(out)
            check_selection(seqs, cfg)
            identity = run_identity("adapt", settings, [s.path for s in seqs], init)
            start_run(
                out, "adapt", identity, resume, input=cfg.input, sequences=[str(s.path) for s in seqs], init=str(init)
            )
        except Exception as exc:  # noqa: BLE001 (re-raised on every process just below)
            error = exc
    raise_shared(error, world)


def restored(
    state: dict, model: DepthGenerator, opt: torch.optim.Optimizer, last: Path
) -> tuple[int, float, int, float]:
    """Model and optimiser from a resume state; the epoch to go on from, the best validation MAE, the epochs since
    it and the minutes spent."""
    try:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
    except (RuntimeError, ValueError, KeyError) as exc:
        raise DataError(last, f"does not fit the network adapted: {exc}") from exc
    return state["epoch"] + 1, state["best_val_mae_m"], state["since_best"], state["minutes"]


def check_selection(seqs: list[Sequence], cfg: AdaptConfig) -> None:
    """Refuse a sequence given twice, and a selection too short to hold a frame out for validation (every
    `val_every`-th frame from the middle of the first `val_every`)."""
    twice = sorted({str(s.path) for s in seqs if sum(t.path == s.path for t in seqs) > 1})
    if twice:
        raise DataError(twice[0], "given more than once: each sequence adapts the generator once")
    n = sum(len(range(len(s))[cfg.start : cfg.end]) for s in seqs)
    if cfg.val_every and n <= cfg.val_every // 2:
        raise DataError(
            seqs[0].path,
            f"{n} frame(s) selected; adaptation holds every {cfg.val_every}th frame out "
            f"for validation and needs at least {cfg.val_every // 2 + 1} (or set "
            "adapt.val_every: 0 to adapt without validation or early stopping)",
        )


def train_epoch(
    model: DepthGenerator,
    step: torch.nn.Module,
    opt: torch.optim.Optimizer,
    train: list[AdaptFrame],
    cfg: AdaptConfig,
    epoch: int,
    gen: torch.Generator,
    rank: int,
    world: int,
    progress: bool,
) -> list[float]:
    """One epoch over the training frames (each with one of its splits, the same on every process); returns the
    loss sum, the number of batches, the hidden-return error sum and its count, summed over the processes."""
    # BatchNorm stays in inference mode: a few frames of one clip per batch would give it noisy
    # statistics (the usual practice when fine-tuning with small batches); every weight still trains
    model.eval()
    order = torch.randperm(len(train), generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch)).tolist()
    # the same on every process
    items = [(train[j], train[j].splits[int(torch.randint(len(train[j].splits), (1,), generator=gen))]) for j in order]
    losses, err, cnt = [], 0.0, 0
    bar = tqdm(
        batches(items, cfg.batch_size), desc=f"adapt epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress
    )
    for b in bar:  # the batches of one process; with several, each takes its share of every batch
        part, weight = share(b, rank, world)
        opt.zero_grad()
        loss, e, c = step(part)
        (loss * weight).backward()  # weight 1.0 for a single process
        opt.step()
        if weight > 0:
            losses.append(float(loss.detach()))
            err, cnt = err + e, cnt + c
            bar.set_postfix(loss=f"{losses[-1]:.3f}")
    return all_sum([sum(losses), len(losses), err, cnt], world)


def finish(
    model: DepthGenerator,
    frames: list[AdaptFrame],
    val: list[AdaptFrame],
    record: dict,
    out: Path,
    cfg: AdaptConfig,
    init: Path,
    seqs: list[Sequence],
    rank: int,
    world: int,
) -> None:
    """The best epoch's weights, how far to trust them over their prior (GeneratorConfig.blend, chosen on the
    validation frames), and the int8 runtime's calibration table measured on the user's own frames."""
    lead = rank == 0
    if val:
        barrier(world)
        kept = torch.load(out / "generator.pt", map_location="cpu", weights_only=False)
        model.load_state_dict(kept["model"])
        blend, by_blend = choose_blend(model, val, rank, world)
        model.cfg = replace(model.cfg, blend=blend)
        record.update({"blend": blend, "val_mae_m_by_blend": {str(w): e for w, e in by_blend.items()}})
        if lead:
            save_best(model, out, cfg, init, seqs, kept["epoch"], kept["val_mae_m"], blend_val_mae_m=by_blend[blend])
    if lead:
        kept = torch.load(out / "generator.pt", map_location="cpu", weights_only=False)
        model.load_state_dict(kept["model"])
        kept["int8_ranges"] = calibrate_generator(model, network_feeds(frames))
        save_checkpoint(out / "generator.pt", kept)
        write_text(out / "summary.json", json.dumps(record, indent=2) + "\n")
    barrier(world)


def finite(x: float) -> float | None:
    """x for a log or checkpoint; None (JSON null) where there is no figure (no validation frames)."""
    return float(x) if x is not None and np.isfinite(x) else None


def save_best(
    model: DepthGenerator,
    out: Path,
    cfg: AdaptConfig,
    init: Path,
    seqs: list[Sequence],
    epoch: int,
    val_mae: float,
    **extra: float,
) -> None:
    """The adapted generator in the trainer's checkpoint format (load_generator reads it)."""
    save_checkpoint(
        out / "generator.pt",
        {
            "model": model.state_dict(),
            "network": model.cfg.__dict__,
            "config": cfg.model_dump(),
            "epoch": epoch,
            "val_mae_m": finite(val_mae),
            "adapted_from": str(init),
            "sequences": [str(s.path) for s in seqs],
            **extra,
        },
    )
