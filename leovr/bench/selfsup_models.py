"""What `leovr bench selfsup` trains and scores with: the models' held-out metrics, the untrained network, the
supervised reference, and self-supervised runs that resume and count their minutes."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from leovr.bench.config import BenchSelfSupConfig
from leovr.config import CompleteConfig, SelfSupConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.data.sequence import Sequence
from leovr.depth.epochs import Epoch, train_epochs
from leovr.depth.inference import forward_padded, load_generator, predict_at_focal
from leovr.depth.network import DepthGenerator
from leovr.depth.train import depth_loss, optimiser
from leovr.depth.train_state import config_changes, generator_config, save_generator
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.pipeline.completion import prepare_sample
from leovr.pipeline.refine import run_refine
from selfsup.supervision import train_frames
from selfsup.trainer import train_selfsup

SHIPPED_FOCAL_PX = 260.0  # the shipped generator's training focal length (the simulator camera's)


def held_out_metrics(seqs: list[Sequence], input_name: str, bins: list[float], predict) -> dict:
    """Depth metrics of `predict(sample, image)` (a depth map) over every frame of the sequences (dense ground
    truth, else held-out beams)."""
    acc = DepthMetricAccumulator(bins)
    ccfg = CompleteConfig(input=input_name)
    for seq in seqs:
        for i in range(len(seq)):
            s = prepare_sample(seq[i], ccfg)
            image = s.frame.image if s.frame.image.ndim == 3 else np.repeat(s.frame.image[..., None], 3, axis=2)
            acc.add(predict(s, image), s.gt)
    r = acc.result()
    return {"mae_m": r["mae_m"], "rmse_m": r["rmse_m"], "absrel": r.get("absrel"), "delta1": r.get("delta1")}


@torch.no_grad()
def score(
    model: DepthGenerator, seqs: list[Sequence], input_name: str, focal_px: float | None, bins: list[float]
) -> dict:
    """Depth metrics of a model (run at `focal_px`) over every frame of the sequences."""
    model.eval()
    return held_out_metrics(
        seqs,
        input_name,
        bins,
        lambda s, image: predict_at_focal(model, image, s.sparse, float(s.frame.K[0, 0]), focal_px)[0],
    )


def untrained_generator(cfg: SelfSupConfig) -> DepthGenerator:
    """Untrained weights drawn with cfg.seed, as the trainer seeds, whatever ran before: the untrained
    figures do not depend on what the bench trained first."""
    with torch.random.fork_rng():
        torch.manual_seed(cfg.seed)
        return DepthGenerator(generator_config(cfg))


def train_supervised_reference(cfg: SelfSupConfig, sequences: list[Path], out: Path, progress: bool) -> Path:
    """The same network, frames, input, resolution and schedule as the self-supervised run, with an L1
    loss on ground-truth depth instead: the bench's 'supervised' figure. Reused when it finished with
    the same settings (a few minutes: no per-epoch resume)."""
    t0 = time.time()
    final = out / "generator.pt"
    if final.is_file() and not config_changes(torch.load(final, weights_only=False).get("config", {}), cfg):
        return final
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    samples = []
    for p in sequences:
        seq = open_sequence(p)
        for f in train_frames(seq, cfg):
            gt = seq[f.index].depth
            gt = cv2.resize(gt, (f.sparse.shape[1], f.sparse.shape[0]), interpolation=cv2.INTER_NEAREST)
            samples.append(
                {
                    "image": torch.from_numpy(f.image).permute(2, 0, 1).float() / 255.0,
                    "sparse": torch.from_numpy(f.sparse)[None],
                    "gt": torch.from_numpy(gt.astype(np.float32))[None],
                }
            )
    model = DepthGenerator(generator_config(cfg))
    opt, sched = optimiser(model.depth_parameters(), cfg)

    def begin(epoch: int) -> Epoch:
        model.train()
        order = torch.randperm(len(samples), generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))
        chunks = (order[k : k + cfg.batch_size] for k in range(0, len(order), cfg.batch_size))
        batches = (
            {k: torch.stack([samples[int(j)][k] for j in chunk]) for k in ("image", "sparse", "gt")} for chunk in chunks
        )
        return Epoch(batches, opt, l1_loss, f"supervised reference, epoch {epoch + 1}/{cfg.epochs}")

    def l1_loss(b: dict) -> tuple[torch.Tensor, dict[str, float]]:
        depth, _ = forward_padded(model, b["image"], b["sparse"])
        loss = depth_loss(depth, b["gt"], "l1")
        return loss, {"loss": loss.item()}

    def end(epoch: int, means: dict[str, float], seconds: float) -> dict:
        sched.step()
        return {"epoch": epoch + 1, **means}

    train_epochs(range(cfg.epochs), begin, end, progress)
    save_generator(final, model, cfg, mode="supervised")
    minutes_spent(out, (time.time() - t0) / 60.0)
    return final


def base_config(cfg: BenchSelfSupConfig, epochs: int, max_frames: int | None = None, **update) -> SelfSupConfig:
    """The bench's self-supervised settings (simulator input, half resolution), with `update` on top."""
    return SelfSupConfig(
        epochs=epochs,
        batch_size=cfg.batch_size,
        lr=cfg.lr,
        channels=cfg.channels,
        train_focal_px=cfg.train_focal_px,
        input="full",
        max_frames=max_frames,
        **update,
    )


def train_run(
    cfg: SelfSupConfig,
    sequences: list[Path],
    run: Path,
    progress: bool,
    share_init: Path | None = None,
    oracle_masks: bool = False,
) -> tuple[Path, float]:
    """Self-supervised run (resumed when interrupted); returns (generator.pt, minutes spent on it over
    every invocation, kept in `train_minutes.json`). `oracle_masks`: the bound of `train_selfsup`; keep
    such a run in its own folder (the flag is not part of the config that resuming checks)."""
    t0 = time.time()
    done = run / "generator.pt"
    last = run / "checkpoint_last.pt"
    if last.is_file():
        state = torch.load(last, weights_only=False)
        if config_changes(state.get("config", {}), cfg):
            print(f"{run}: left by a run with other settings, starting it again")
            shutil.rmtree(run)
        elif done.is_file() and state["epoch"] + 1 >= cfg.epochs:
            return done, minutes_spent(run)
    if share_init is not None and share_init.is_dir() and not (run / "graph" / "init").exists():
        # the initialisation pass uses no network: same for every run
        shutil.copytree(share_init, run / "graph" / "init")
    train_selfsup(cfg, sequences, run, run_refine, resume=last.is_file(), progress=progress, oracle_masks=oracle_masks)
    return done, minutes_spent(run, (time.time() - t0) / 60.0)


def minutes_spent(run: Path, add: float = 0.0) -> float:
    """Training minutes of a run, summed over interrupted and resumed invocations."""
    path = run / "train_minutes.json"
    total = (json.loads(path.read_text())["minutes"] if path.is_file() else 0.0) + add
    if add:
        write_text(path, json.dumps({"minutes": round(total, 2)}) + "\n")
    return total


def score_paths(checkpoint: Path, tests: list[Sequence], cfg: BenchSelfSupConfig, bins: list[float]) -> dict:
    return score(load_generator(checkpoint), tests, "full", cfg.train_focal_px, bins)
