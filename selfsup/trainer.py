"""Cold-start self-supervised training of the depth generator (LeoVR Sec. IV, V-A).

Epochs split in two stages: the initialisation stage (first `init_fraction` of the epochs) learns from
the photometric loss, the landmarks (L_f) and smoothness with poses from a graph that trusts no
network (IP-Basic depth, point factors only); the refinement stage re-runs the full graph with the
current generator every `refresh_every` epochs and adds the refined-depth guidance (L_r).

The sequences are wrapped in `BlindSequence`: no ground-truth depth or pose reaches this module.
Every epoch writes `checkpoint_last.pt` (resume) and `generator.pt` (what `--checkpoint` loads)
atomically and a line of `log.jsonl` / `log.csv`; the last epoch's `generator.pt` also holds its int8
calibration table, measured on the training frames' inputs (leovr.depth.quantize), so that `leovr refine`
runs it as it runs the shipped generator. Several processes started by `torchrun` train one
model with DistributedDataParallel (gloo, CPU): rank 0 runs the graph passes and writes the files.

One batch's loss is `selfsup.objective`'s; the epoch loop (`leovr.depth.epochs`) and the files kept between epochs
(`leovr.depth.train_state`) are supervised training's; the `--rerun` recording is `selfsup.train_rerun`'s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, DistributedSampler, RandomSampler

from leovr.config import SelfSupConfig
from leovr.data import open_sequence
from leovr.data.io import check_output_dir, check_output_file
from leovr.data.run_info import folder_fingerprint
from leovr.depth.epochs import Epoch, train_epochs
from leovr.depth.inference import forward_padded, predict
from leovr.depth.network import DepthGenerator
from leovr.depth.runtime import InputRecorder, calibrate_generator
from leovr.depth.train import init_from, optimiser
from leovr.depth.train_state import (
    append_logs,
    generator_config,
    resume_from,
    save_generator,
    save_last,
)
from leovr.errors import DataError
from leovr.threads import single_threaded_blas
from selfsup.blind import BlindSequence
from selfsup.dataset import SelfSupSamples, image_tensor
from selfsup.distributed import barrier, distributed
from selfsup.objective import TERMS, batch_terms
from selfsup.supervision import PosePass, TrainFrame, at_training_size, build_supervision, graph_pass, train_frames
from selfsup.train_rerun import RerunView


def init_epochs(cfg: SelfSupConfig) -> int:
    return int(round(cfg.epochs * cfg.init_fraction))


def pass_tag(epoch: int, cfg: SelfSupConfig) -> str:
    """Which graph pass supervises this epoch: 'init', or 'refine_eN' renewed every `refresh_every`."""
    n = init_epochs(cfg)
    if epoch < n:
        return "init"
    return f"refine_e{n + cfg.refresh_every * ((epoch - n) // cfg.refresh_every) + 1}"


@single_threaded_blas
def train_selfsup(
    cfg: SelfSupConfig,
    sequences: list[Path],
    out: Path,
    pose_pass: PosePass,
    resume: bool = False,
    progress: bool = True,
    rerun: Path | None = None,
    oracle_masks: bool = False,
) -> dict:
    """Train on raw sequences; returns the last epoch's log record (empty on ranks other than 0). `pose_pass`:
    the window graph that gives the poses, landmarks and refined depth (`leovr.pipeline.refine.run_refine`).

    `oracle_masks`: a bound for benchmarks on rendered sequences, not a method. The photometric mask is the
    simulator's moving mask (ground truth), in place of eq. 19 and every other test."""
    return fit(cfg, sequences, out, pose_pass, resume, progress, rerun, oracle_masks)[0]


def oracle_moving(seq: BlindSequence, frames: list[TrainFrame]) -> list[np.ndarray]:
    """The true moving mask of each training frame, at its training resolution (ground truth: bounds only)."""
    out = []
    for f in frames:
        m = seq.base[f.index].moving_mask
        if m is None:
            raise DataError(seq.path, f"frame {f.index} has no moving mask; oracle masks need a rendered sequence")
        out.append(at_training_size(m, f))
    return out


def init_network(cfg: SelfSupConfig) -> DepthGenerator:
    """The network fine-tuning starts from (`init_checkpoint`)."""
    model = DepthGenerator(generator_config(cfg))
    init_from(model, Path(cfg.init_checkpoint))
    return model


@torch.no_grad()
def start_depths(model: DepthGenerator, frames: list[TrainFrame]) -> None:
    """Each frame's depth from `model` on its own input (TrainFrame.anchor), as training runs the network."""
    model.eval()
    for f in frames:
        depth, _ = forward_padded(model, image_tensor(f.image)[None], torch.from_numpy(f.sparse)[None, None])
        f.anchor = depth[0, 0].numpy()


def epoch_sampler(dataset: SelfSupSamples, cfg: SelfSupConfig, epoch: int, rank: int, world: int):
    """This process's share of the samples for the epoch, shuffled by (seed, epoch)."""
    if world > 1:
        sampler = DistributedSampler(dataset, world, rank, shuffle=True, seed=cfg.seed)
        sampler.set_epoch(epoch)
        return sampler
    return RandomSampler(dataset, generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))


def batch_loss(
    net: torch.nn.Module, b: dict, cfg: SelfSupConfig, refine: bool
) -> tuple[torch.Tensor, dict[str, float]]:
    """Eq. 22 on one batch, with the masked-LiDAR term on the network's depth from the batch's thinner input."""
    depth, log_sigma = forward_padded(net, b["image"], b["sparse"])
    masked = forward_padded(net, b["image"], b["masked_sparse"])[0] if cfg.weight_masked > 0 else None
    loss, terms, _ = batch_terms(depth, b, cfg, refine, log_sigma, masked)
    return loss, terms


def fit(
    cfg: SelfSupConfig,
    sequences: list[Path],
    out: Path,
    pose_pass: PosePass,
    resume: bool = False,
    progress: bool = True,
    rerun: Path | None = None,
    oracle_masks: bool = False,
) -> tuple[dict, DepthGenerator]:
    """`train_selfsup`, also returning this process's model."""
    if not sequences:
        raise DataError("sequences", "self-supervised training needs at least one sequence folder")
    rank, world = distributed()
    out = check_output_dir(Path(out))
    if rerun is not None:
        check_output_file(Path(rerun))
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    seqs = [BlindSequence(open_sequence(p)) for p in sequences]
    frames = [train_frames(s, cfg) for s in seqs]
    moving = [oracle_moving(s, f) for s, f in zip(seqs, frames)] if oracle_masks else [None] * len(seqs)
    model = DepthGenerator(generator_config(cfg))
    if cfg.init_checkpoint:
        if not resume:
            init_from(model, Path(cfg.init_checkpoint))
        if cfg.weight_anchor > 0:  # the starting network's depth (resuming: read from the checkpoint again)
            start_depths(init_network(cfg) if resume else model, [f for fs in frames for f in fs])
    # the head learns from its NLL only, and the NLL (metres: hundreds at a cold start) never reaches the depth path
    model.sigma_on_detached = True
    params = model.parameters() if cfg.weight_nll > 0 else model.depth_parameters()
    opt, sched = optimiser(params, cfg)
    last = out / "checkpoint_last.pt"
    inputs = {str(Path(p).resolve()): folder_fingerprint(Path(p)) for p in sequences}
    optimisers = {"optimizer": opt, "scheduler": sched}
    start = resume_from(last, model, optimisers, cfg, inputs)["epoch"] + 1 if resume else 0
    net = torch.nn.parallel.DistributedDataParallel(model, find_unused_parameters=True) if world > 1 else model

    def supervise(tag: str) -> SelfSupSamples:
        """Graph passes for this tag (rank 0 runs them; the others wait, then read them), and the targets."""
        folder = out / "graph" / tag
        checkpoint = None
        if tag != "init":
            checkpoint = folder / "generator.pt"
            if rank == 0 and not checkpoint.is_file():
                save_generator(checkpoint, model, cfg)
        if rank != 0:
            barrier(world)
        graphs = [
            graph_pass(s, cfg, folder / f"seq{k}", checkpoint, len(frames[k]), pose_pass, progress and rank == 0)
            for k, s in enumerate(seqs)
        ]
        if rank == 0:
            barrier(world)
        sup = [
            build_supervision(
                frames[k], g, cfg, tag != "init", folder / f"seq{k}" / "masks" if rank == 0 else None, moving[k]
            )
            for k, g in enumerate(graphs)
        ]
        if dataset is None:
            return SelfSupSamples(frames, sup)
        dataset.set_supervision(sup)
        return dataset

    dataset: SelfSupSamples | None = None
    tag, viewer = None, None

    def begin(epoch: int) -> Epoch:
        """The epoch's graph pass (renewed when its tag changes) and this process's share of the samples."""
        nonlocal tag, dataset, viewer
        refine = epoch >= init_epochs(cfg)
        if pass_tag(epoch, cfg) != tag:
            tag = pass_tag(epoch, cfg)
            dataset = supervise(tag)
        if len(dataset) == 0:
            raise DataError(sequences[0], "no frame has both neighbours: sequences need at least 3 frames")
        if rerun is not None and rank == 0 and viewer is None:
            viewer = RerunView(Path(rerun), cfg, dataset)
        net.train()
        loader = DataLoader(dataset, cfg.batch_size, sampler=epoch_sampler(dataset, cfg, epoch, rank, world))
        label = f"epoch {epoch + 1}/{cfg.epochs} ({'refinement' if refine else 'initialisation'})"
        return Epoch(loader, opt, lambda b: batch_loss(net, b, cfg, refine), label)

    def end(epoch: int, means: dict[str, float], seconds: float) -> dict:
        """The schedule, then on rank 0 the logs, `checkpoint_last.pt` and `generator.pt`; empty on other ranks."""
        refine = epoch >= init_epochs(cfg)
        sched.step()
        if world > 1:  # gradients are averaged every step; BatchNorm statistics only at the next forward: sync now
            for buf in model.buffers():
                dist.broadcast(buf, 0)
        record: dict = {}
        if rank == 0:
            record = {
                "epoch": epoch + 1,
                "stage": "refinement" if refine else "initialisation",
                "graph_pass": tag,
                **{k: means.get(k, 0.0) for k in TERMS},
                "lr": opt.param_groups[0]["lr"],
                "seconds": round(seconds, 1),
                "processes": world,
            }
            append_logs(out, record)
            save_last(last, model, optimisers, epoch, cfg, inputs)
            # the last epoch's generator carries its int8 calibration table
            table = int8_table(model, [f for fs in frames for f in fs]) if epoch + 1 == cfg.epochs else {}
            save_generator(out / "generator.pt", model, cfg, epoch=epoch + 1, mode="selfsup", **table)
            if viewer is not None:
                viewer.log(epoch + 1, model, dataset, cfg, refine)
        barrier(world)
        return record

    return train_epochs(range(start, cfg.epochs), begin, end, progress and rank == 0), model


CALIBRATION_FRAMES = 32  # training frames (spread over the sequences) the int8 ranges are measured on


@torch.no_grad()
def int8_table(model: DepthGenerator, frames: list[TrainFrame]) -> dict:
    """The checkpoint entry `int8_ranges` of `model` (none for a network without a prior, or without frames),
    measured on the network inputs of up to CALIBRATION_FRAMES training frames as inference builds them
    (leovr.depth.quantize)."""
    if not model.uses_prior or not frames:
        return {}
    recorder = InputRecorder(model)
    for f in frames[:: max(1, -(-len(frames) // CALIBRATION_FRAMES))]:
        predict(recorder, f.image, f.sparse)
    ranges = calibrate_generator(model, recorder.feeds)
    model.train()
    return {"int8_ranges": ranges}
