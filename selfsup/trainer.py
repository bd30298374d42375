"""Cold-start self-supervised training of the depth generator (LeoVR Sec. IV, V-A).

Epochs split in two stages: the initialisation stage (first `init_fraction` of the epochs) learns from
the photometric loss, the landmarks (L_f) and smoothness with poses from a graph that trusts no
network (IP-Basic depth, point factors only); the refinement stage re-runs the full graph with the
current generator every `refresh_every` epochs and adds the refined-depth guidance (L_r).

The sequences are wrapped in `BlindSequence`: no ground-truth depth or pose reaches this module.
Every epoch writes `checkpoint_last.pt` (resume) and `generator.pt` (what `--checkpoint` loads)
atomically and a line of `log.jsonl` / `log.csv`. Several processes started by `torchrun` train one
model with DistributedDataParallel (gloo, CPU): rank 0 runs the graph passes and writes the files.
"""

from __future__ import annotations

import csv
import io
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DataLoader, DistributedSampler, RandomSampler
from tqdm import tqdm

from leovr.config import SelfSupConfig
from leovr.data import open_sequence
from leovr.data.io import check_output_dir, check_output_file, write_text
from leovr.data.run_info import folder_fingerprint
from leovr.depth.inference import forward_padded
from leovr.depth.layers import gaussian_nll
from leovr.depth.network import DepthGenerator
from leovr.depth.train import generator_config, init_from, load_resume, save_checkpoint
from leovr.errors import DataError
from leovr.threads import single_threaded_blas
from selfsup.blind import BlindSequence
from selfsup.dataset import SelfSupSamples
from selfsup.distributed import barrier, distributed
from selfsup.losses import (
    feature_point_loss,
    photometric_error,
    photometric_loss,
    refined_depth_loss,
    sparse_depth_loss,
    second_order_smoothness,
)
from selfsup.supervision import PosePass, TrainFrame, at_training_size, build_supervision, graph_pass, train_frames
from selfsup.warp import warp_image

TERMS = ("loss", "photometric", "feature", "refined", "smooth", "nll", "sparse", "mask_kept", "refined_used")


RERUN_FRAMES = 2  # frames logged to --rerun each epoch


def init_epochs(cfg: SelfSupConfig) -> int:
    return int(round(cfg.epochs * cfg.init_fraction))


def config_changes(saved: dict, cfg: SelfSupConfig) -> list[str]:
    """Settings in which a run's saved config differs from `cfg`; a setting the saved config lacks (added
    to leovr after the run began) counts as its default."""
    default = SelfSupConfig().model_dump()
    return sorted(k for k, v in cfg.model_dump().items() if saved.get(k, default[k]) != v)


def pass_tag(epoch: int, cfg: SelfSupConfig) -> str:
    """Which graph pass supervises this epoch: 'init', or 'refine_eN' renewed every `refresh_every`."""
    n = init_epochs(cfg)
    if epoch < n:
        return "init"
    return f"refine_e{n + cfg.refresh_every * ((epoch - n) // cfg.refresh_every) + 1}"


def photometric_term(
    img: torch.Tensor, depth: torch.Tensor, b: dict, cfg: SelfSupConfig
) -> tuple[torch.Tensor, list[torch.Tensor], list[torch.Tensor]]:
    """L_p (eq. 16) with the masks of the batch: (loss, warped neighbours, kept pixels per neighbour).
    With `auto_mask` (monodepth2), a pixel also drops out against a neighbour it matches better
    unwarped (a mover at the ego's speed, a standing camera), and the loss takes the per-pixel
    minimum over the neighbours that keep it."""
    warped, masks, errors = [], [], []
    for side in ("prev", "next"):
        w, inside = warp_image(b[side], depth, b[f"T_{side}"], b["K"])
        keep = inside & (b[f"mask_{side}"] > 0.5)
        err = photometric_error(img, w)
        if cfg.auto_mask:
            keep = keep & (err.detach() < photometric_error(img, b[side]))
        warped.append(w)
        masks.append(keep)
        errors.append(err)
    return photometric_loss(errors, masks, per_pixel_min=cfg.auto_mask), warped, masks


def batch_terms(
    depth: torch.Tensor, b: dict, cfg: SelfSupConfig, refine_stage: bool, log_sigma: torch.Tensor | None = None
) -> tuple[torch.Tensor, dict[str, float], dict[str, torch.Tensor]]:
    """Eq. 22 on one batch, plus the uncertainty head's Gaussian NLL at the LiDAR-backed landmarks
    (on detached depth, and the head sees detached features: it trains the head only): (total loss,
    detached terms, images)."""
    img = b["image"]
    lp, warped, masks = photometric_term(img, depth, b, cfg)
    lf = (
        feature_point_loss(depth, b["feature_depth"], cfg.target_loss)
        if cfg.weight_feature > 0
        else depth.new_zeros(())
    )
    use_r = refine_stage and cfg.weight_refined > 0 and bool(b["use_refined"].any())
    lr = refined_depth_loss(depth, b["refined"], b["use_refined"], cfg.target_loss) if use_r else depth.new_zeros(())
    ls = second_order_smoothness(depth, img) if cfg.weight_smooth > 0 else depth.new_zeros(())
    lz = sparse_depth_loss(depth, b["sparse"], cfg.target_loss) if cfg.weight_sparse > 0 else depth.new_zeros(())
    nll = depth.new_zeros(())
    if cfg.weight_nll > 0 and log_sigma is not None:
        nll = gaussian_nll(depth.detach(), log_sigma, b["feature_depth"], (b["feature_depth"] > 0).to(depth.dtype))
    loss = (
        lp
        + cfg.weight_feature * lf
        + cfg.weight_refined * lr
        + cfg.weight_smooth * ls
        + cfg.weight_nll * nll
        + cfg.weight_sparse * lz
    )
    terms = {
        "loss": loss.item(),
        "photometric": lp.item(),
        "feature": lf.item(),
        "refined": lr.item(),
        "smooth": ls.item(),
        "nll": nll.item(),
        "sparse": lz.item(),
        "mask_kept": float(torch.cat(masks).float().mean()),
        "refined_used": float(b["use_refined"].float().mean()) if refine_stage else 0.0,
    }
    return loss, terms, {"warped_prev": warped[0], "mask_prev": masks[0]}


class _Rerun:
    """Flow mask, warped neighbour, photometric error and depth of a few frames, once per epoch."""

    def __init__(self, path: Path, cfg: SelfSupConfig, dataset: SelfSupSamples) -> None:
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream("leovr_selfsup")
        path.parent.mkdir(parents=True, exist_ok=True)
        self.rec.save(str(path))
        n = len(dataset)
        self.picks = sorted({int(round(x)) for x in np.linspace(0, n - 1, min(RERUN_FRAMES, n))})

    @torch.no_grad()
    def log(
        self, epoch: int, model: torch.nn.Module, dataset: SelfSupSamples, cfg: SelfSupConfig, refine: bool
    ) -> None:
        rr = self.rr
        self.rec.set_time("epoch", sequence=epoch)
        model.eval()
        for j in self.picks:
            b = {k: v[None] for k, v in dataset[j].items()}
            depth, _ = forward_padded(model, b["image"], b["sparse"])
            _, _, extra = batch_terms(depth, b, cfg, refine)
            pe = photometric_error(b["image"], extra["warped_prev"])[0, 0]
            k, i = (int(x) for x in b["key"][0])
            base = f"train/seq{k}/frame{i:06d}"
            to_u8 = lambda t: (t.clamp(0, 1) * 255).byte().permute(1, 2, 0).numpy()  # noqa: E731
            self.rec.log(f"{base}/image", rr.Image(to_u8(b["image"][0])))
            self.rec.log(f"{base}/warped_prev", rr.Image(to_u8(extra["warped_prev"][0])))
            self.rec.log(f"{base}/flow_mask_prev", rr.Image(extra["mask_prev"][0, 0].byte().numpy() * 255))
            self.rec.log(f"{base}/photometric_error", rr.Image((pe.clamp(0, 0.5) * 510).byte().numpy()))
            self.rec.log(f"{base}/depth", rr.DepthImage(depth[0, 0].float().numpy(), meter=1.0, colormap="turbo"))
        model.train()


def _append_logs(out: Path, record: dict) -> None:
    with open(out / "log.jsonl", "a") as fh:
        fh.write(json.dumps(record) + "\n")
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines() if line.strip()]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[-1]))
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "log.csv", buf.getvalue())


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


def resumed_epoch(
    last: Path,
    model: DepthGenerator,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    cfg: SelfSupConfig,
    inputs: dict[str, str],
) -> int:
    """The epoch to go on from, the model, optimiser and schedule restored from `last`; a checkpoint trained
    with other settings (other than the number of epochs) or on other recordings (`inputs`: path -> content
    fingerprint) is refused."""
    state = load_resume(last, model, opt, sched)
    changed = [k for k in config_changes(state.get("config", {}), cfg) if k != "epochs"]
    if changed:
        raise DataError(
            last,
            f"was trained with other settings ({', '.join(changed)}); resume with the same "
            "config (only epochs may change) or start a new --out folder",
        )
    before = state.get("sequences")
    if before is not None and before != inputs:
        other = sorted(set(before.items()) ^ set(inputs.items()))
        raise DataError(
            last,
            f"was trained on other recordings or other contents ({', '.join(p for p, _ in other)}); "
            "resume with the same sequences or start a new --out folder",
        )
    return state["epoch"] + 1


def epoch_sampler(dataset: SelfSupSamples, cfg: SelfSupConfig, epoch: int, rank: int, world: int):
    """This process's share of the samples for the epoch, shuffled by (seed, epoch)."""
    if world > 1:
        sampler = DistributedSampler(dataset, world, rank, shuffle=True, seed=cfg.seed)
        sampler.set_epoch(epoch)
        return sampler
    return RandomSampler(dataset, generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))


def train_epoch(
    net: torch.nn.Module,
    loader: DataLoader,
    opt: torch.optim.Optimizer,
    cfg: SelfSupConfig,
    refine: bool,
    desc: str,
    show: bool,
) -> dict[str, float]:
    """One pass over the loader, a step per batch; the mean of each loss term."""
    net.train()
    sums, count = dict.fromkeys(TERMS, 0.0), 0
    bar = tqdm(loader, desc=desc, unit="batch", disable=not show)
    for b in bar:
        depth, log_sigma = forward_padded(net, b["image"], b["sparse"])
        loss, terms, _ = batch_terms(depth, b, cfg, refine, log_sigma)
        opt.zero_grad()
        loss.backward()
        opt.step()
        for k in TERMS:
            sums[k] += terms[k]
        count += 1
        bar.set_postfix(loss=f"{terms['loss']:.3f}")
    return {k: sums[k] / max(count, 1) for k in TERMS}


def save_epoch(
    out: Path,
    model: DepthGenerator,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    epoch: int,
    cfg: SelfSupConfig,
    inputs: dict[str, str],
) -> None:
    """The state to resume from (`checkpoint_last.pt`, with the recordings' fingerprints `inputs`) and the
    generator as trained so far (`generator.pt`)."""
    network, config = generator_config(cfg).__dict__, cfg.model_dump()
    save_checkpoint(
        out / "checkpoint_last.pt",
        {
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "epoch": epoch,
            "config": config,
            "network": network,
            "sequences": inputs,
        },
    )
    save_checkpoint(
        out / "generator.pt",
        {"model": model.state_dict(), "network": network, "config": config, "epoch": epoch + 1, "mode": "selfsup"},
    )


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
    if cfg.init_checkpoint and not resume:
        init_from(model, Path(cfg.init_checkpoint))
    # the head learns from its NLL only, and the NLL (metres: hundreds at a cold start) never reaches the depth path
    model.sigma_on_detached = True
    params = model.parameters() if cfg.weight_nll > 0 else model.depth_parameters()
    opt = torch.optim.Adam(params, lr=cfg.lr, betas=(0.9, 0.999))
    sched = torch.optim.lr_scheduler.StepLR(opt, cfg.lr_step_epochs, cfg.lr_gamma)
    last = out / "checkpoint_last.pt"
    inputs = {str(Path(p).resolve()): folder_fingerprint(Path(p)) for p in sequences}
    start = resumed_epoch(last, model, opt, sched, cfg, inputs) if resume else 0
    net = torch.nn.parallel.DistributedDataParallel(model, find_unused_parameters=True) if world > 1 else model
    network = generator_config(cfg).__dict__

    def supervise(tag: str) -> SelfSupSamples:
        """Graph passes for this tag (rank 0 runs them; the others wait, then read them), and the targets."""
        folder = out / "graph" / tag
        checkpoint = None
        if tag != "init":
            checkpoint = folder / "generator.pt"
            if rank == 0 and not checkpoint.is_file():
                save_checkpoint(
                    checkpoint, {"model": model.state_dict(), "network": network, "config": cfg.model_dump()}
                )
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
    tag, record, viewer = None, {}, None
    for epoch in range(start, cfg.epochs):
        refine = epoch >= init_epochs(cfg)
        if pass_tag(epoch, cfg) != tag:
            tag = pass_tag(epoch, cfg)
            dataset = supervise(tag)
        if len(dataset) == 0:
            raise DataError(sequences[0], "no frame has both neighbours: sequences need at least 3 frames")
        if rerun is not None and rank == 0 and viewer is None:
            viewer = _Rerun(Path(rerun), cfg, dataset)
        loader = DataLoader(dataset, cfg.batch_size, sampler=epoch_sampler(dataset, cfg, epoch, rank, world))
        t0 = time.time()
        means = train_epoch(
            net,
            loader,
            opt,
            cfg,
            refine,
            f"epoch {epoch + 1}/{cfg.epochs} ({'refinement' if refine else 'initialisation'})",
            progress and rank == 0,
        )
        sched.step()
        if (
            world > 1
        ):  # gradients are averaged every step; BatchNorm statistics only at the next forward, so sync them now
            for buf in model.buffers():
                dist.broadcast(buf, 0)
        if rank == 0:
            record = {
                "epoch": epoch + 1,
                "stage": "refinement" if refine else "initialisation",
                "graph_pass": tag,
                **means,
                "lr": opt.param_groups[0]["lr"],
                "seconds": round(time.time() - t0, 1),
                "processes": world,
            }
            _append_logs(out, record)
            save_epoch(out, model, opt, sched, epoch, cfg, inputs)
            if viewer is not None:
                viewer.log(epoch + 1, model, dataset, cfg, refine)
        barrier(world)
    return record, model
