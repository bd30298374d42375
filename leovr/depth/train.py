"""Supervised training of the depth generator (LeoVR Sec. V-A): Adam, lr halved every 6 epochs, masked
L1/L2 on valid ground truth, then the log-uncertainty head alone with the Gaussian NLL (all-day eq. 2).

The epochs run in the loop self-supervised training runs too (`leovr.depth.epochs`). Every epoch writes
`checkpoint_last.pt` atomically and a line of `log.jsonl` / `log.csv` (`leovr.depth.train_state`); `best.pt` keeps
the weights with the lowest validation MAE. `resume=True` continues from `checkpoint_last.pt` with the settings it
began with (only epochs, sigma_epochs and init_checkpoint may change).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Iterable

import numpy as np
import torch
from torch.utils.data import DataLoader

from leovr.config import OptimiserSettings, TrainConfig
from leovr.data.io import check_output_dir
from leovr.depth.epochs import Epoch, train_epochs
from leovr.depth.dataset import DENSITY_RATIO, NATIVE_PROB, DepthSamples, split_sequences
from leovr.depth.layers import gaussian_nll
from leovr.depth.network import DepthGenerator
from leovr.depth.train_state import append_logs, generator_config, resume_from, save_generator, save_last
from leovr.errors import DataError
from leovr.sim.dataset import default_root
from leovr.threads import single_threaded_blas


def optimiser(
    params: Iterable[torch.nn.Parameter], cfg: OptimiserSettings
) -> tuple[torch.optim.Adam, torch.optim.lr_scheduler.StepLR]:
    """Adam over `params` at the configured rate, and its schedule: the rate times lr_gamma every lr_step_epochs
    epochs (`step()` once per epoch)."""
    opt = torch.optim.Adam(params, lr=cfg.lr, betas=(0.9, 0.999))
    return opt, torch.optim.lr_scheduler.StepLR(opt, cfg.lr_step_epochs, cfg.lr_gamma)


def run_model(model: DepthGenerator, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth and log-sigma of a training batch (with its precomputed prior when it has one)."""
    return model(batch["image"], batch["sparse"], batch.get("prior"))


def depth_loss(pred: torch.Tensor, gt: torch.Tensor, kind: str) -> torch.Tensor:
    valid = (gt > 0).float()
    diff = (pred - gt).abs() if kind == "l1" else (pred - gt) ** 2
    return (diff * valid).sum() / valid.sum().clamp(min=1.0)


def edge_aware_smoothness(depth: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """First-order smoothness of mean-normalised inverse depth, down-weighted at image edges."""
    inv = 1.0 / depth
    inv = inv / inv.mean(dim=(2, 3), keepdim=True)
    dx, dy = (inv[..., :, 1:] - inv[..., :, :-1]).abs(), (inv[..., 1:, :] - inv[..., :-1, :]).abs()
    ix = (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1, keepdim=True)
    iy = (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True)
    return (dx * torch.exp(-ix)).mean() + (dy * torch.exp(-iy)).mean()


@torch.no_grad()
def evaluate(model: DepthGenerator, loader: DataLoader) -> float:
    """Mean absolute error (metres) over valid ground-truth pixels."""
    model.eval()
    err, n = 0.0, 0
    for b in loader:
        depth, _ = run_model(model, b)
        valid = b["gt"] > 0
        err += float((depth - b["gt"]).abs()[valid].sum())
        n += int(valid.sum())
    return err / max(n, 1)


def init_from(model: DepthGenerator, path: Path) -> None:
    """Copy the weights of a trainer checkpoint into `model` (fine-tuning); the networks must match,
    except that an absolute-depth network may start a residual one: every shared layer is copied and
    the residual heads keep their zero start (the network then begins as its classical prior)."""
    from dataclasses import replace

    from leovr.depth.inference import load_generator

    source = load_generator(path)
    if replace(source.cfg, output=model.cfg.output) != model.cfg or (
        source.cfg.output != model.cfg.output and source.cfg.output != "absolute"
    ):
        raise DataError(path, f"init checkpoint describes {source.cfg}, the config asks for {model.cfg}")
    state = source.state_dict()
    if source.cfg.output != model.cfg.output:
        state = {k: v for k, v in state.items() if not k.startswith("depth_head.")}
        model.load_state_dict(state, strict=False)
    else:
        model.load_state_dict(state)


@single_threaded_blas
def train_supervised(cfg: TrainConfig, out: Path, resume: bool = False, progress: bool = True) -> dict:
    """Train; returns the last log record."""
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    root = Path(cfg.dataset) if cfg.dataset else default_root() / cfg.recipe
    prior, image_edges = cfg.output != "absolute", cfg.prior_edges == "image"
    train_set = DepthSamples(
        split_sequences(root, "train"),
        DENSITY_RATIO,
        NATIVE_PROB,
        cfg.max_frames,
        cfg.seed,
        with_prior=prior,
        image_edges=image_edges,
    )
    val_set = DepthSamples(
        split_sequences(root, "val"),
        max_frames=max(8, (cfg.max_frames or 64) // 4),
        seed=cfg.seed + 1,
        random_input=False,
        with_prior=prior,
        image_edges=image_edges,
    )
    gen = torch.Generator().manual_seed(cfg.seed)
    train_loader = DataLoader(
        train_set, cfg.batch_size, shuffle=True, generator=gen, drop_last=len(train_set) > cfg.batch_size
    )
    val_loader = DataLoader(val_set, cfg.batch_size)
    model = DepthGenerator(generator_config(cfg))
    if cfg.init_checkpoint and not resume:
        init_from(model, Path(cfg.init_checkpoint))
    total = cfg.epochs + cfg.sigma_epochs
    opt, sched = optimiser(model.depth_parameters(), cfg)
    sigma_opt = torch.optim.Adam(model.sigma_head.parameters(), lr=cfg.lr)
    check_output_dir(out)
    start, best = 0, float("inf")
    last = out / "checkpoint_last.pt"
    optimisers = {"optimizer": opt, "scheduler": sched, "sigma_optimizer": sigma_opt}
    if resume:
        # how long to train, and the weights it started from (read only at the start)
        longer = ("epochs", "sigma_epochs", "init_checkpoint")
        state = resume_from(last, model, optimisers, cfg, may_change=longer)
        start, best = state["epoch"] + 1, state["best_val_mae_m"]
        gen.set_state(state["generator"])

    def begin(epoch: int) -> Epoch:
        """The depth phase trains the depth path; the sigma phase the uncertainty head alone, the depth path
        frozen (BatchNorm statistics included)."""
        depth_phase = epoch < cfg.epochs
        train_set.epoch = epoch
        model.train()
        for p in model.depth_parameters():
            p.requires_grad_(depth_phase)
        if not depth_phase:
            model.eval()
            model.sigma_head.train()
        label = f"epoch {epoch + 1}/{total} ({'depth' if depth_phase else 'sigma'})"
        step, optimizer = (depth_step, opt) if depth_phase else (sigma_step, sigma_opt)
        return Epoch(train_loader, optimizer, step, label)

    def depth_step(b: dict) -> tuple[torch.Tensor, dict[str, float]]:
        depth, _ = run_model(model, b)
        loss = depth_loss(depth, b["gt"], cfg.loss)
        if cfg.smoothness > 0:
            loss = loss + cfg.smoothness * edge_aware_smoothness(depth, b["image"])
        return loss, {"train_loss": loss.item()}

    def sigma_step(b: dict) -> tuple[torch.Tensor, dict[str, float]]:
        depth, log_sigma = run_model(model, b)  # the depth path has requires_grad off: backward stops at the head
        loss = gaussian_nll(depth.detach(), log_sigma, b["gt"], (b["gt"] > 0).float())
        return loss, {"train_loss": loss.item()}

    def end(epoch: int, means: dict[str, float], seconds: float) -> dict:
        """The schedule, the validation MAE, the logs, `checkpoint_last.pt` and `best.pt`."""
        nonlocal best
        depth_phase = epoch < cfg.epochs
        if depth_phase:
            sched.step()
        t0 = time.time()
        val_mae = evaluate(model, val_loader)
        seconds += time.time() - t0  # the epoch's time with its validation
        record = {
            "epoch": epoch + 1,
            "phase": "depth" if depth_phase else "sigma",
            "train_loss": means.get("train_loss", float("nan")),
            "val_mae_m": val_mae,
            "lr": opt.param_groups[0]["lr"],
            "seconds": round(seconds, 1),
        }
        append_logs(out, record)
        # depth phase: keep the lowest validation MAE; sigma phase: depth is frozen, so every epoch improves best.pt
        save_best = not depth_phase or val_mae < best
        if depth_phase and save_best:
            best = val_mae
        save_last(last, model, optimisers, epoch, cfg, best_val_mae_m=best, generator=gen.get_state())
        if save_best:
            save_generator(out / "best.pt", model, cfg, epoch=epoch + 1, val_mae_m=val_mae, mode="supervised")
        return record

    return train_epochs(range(start, total), begin, end, progress)
