"""Run depth completion over a sequence: simulate the cheap input, complete, write uint16 PNGs
(metres x 256, the KITTI depth-completion convention, recorded in run.json) and score the completed
arrays against ground-truth depth or held-out LiDAR points."""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig
from leovr.data.io import write_depth_png, write_text
from leovr.data.records import Frame
from leovr.data.run_info import png_name, read_run_depth, run_identity, start_run
from leovr.data.sequence import Sequence
from leovr.depth.fills import complete_depth
from leovr.errors import DataError, brief
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.eval.heldout import PARALLAX_REL, PARALLAX_WINDOW, parallax_filter
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor
from leovr.lidar.projection import sparse_depth
from leovr.paths import shipped_checkpoint
from leovr.threads import single_threaded_blas


@dataclass
class EvalSample:
    """What a depth method sees for one frame (`sparse`) and what it is scored against (`gt`)."""

    frame: Frame
    sparse: np.ndarray
    gt: np.ndarray | None
    gt_kind: str  # "dense", "heldout", "none", or "deferred" (held-out truth not built yet: with_truth)
    kept_points: np.ndarray | None = None  # the cheap input's points, LiDAR frame
    # the held-out returns, LiDAR frame (kind "deferred"), or where to take them from
    heldout_points: np.ndarray | TruthScan | None = None


@dataclass
class TruthScan:
    """The held-out returns taken from the frame's scan deskewed with the ground-truth motion (built when the
    truth is), so that every run on a recording with poses is scored against the same truth."""

    scan: Callable[[], np.ndarray]  # the whole scan so deskewed
    heldout_index: np.ndarray


def heldout_truth(frame: Frame, heldout: np.ndarray, cfg: CompleteConfig, scan: np.ndarray | None = None) -> np.ndarray:
    """The held-out returns as a depth map, each dropped where a nearer return of the scan (default the
    frame's) lies within the parallax window (the LiDAR sees background beside an edge that the camera cannot:
    shared data README)."""
    held = sparse_depth(heldout, frame.K, frame.T_cam_lidar, frame.shape)
    every = sparse_depth(frame.points if scan is None else scan, frame.K, frame.T_cam_lidar, frame.shape)
    return parallax_filter(held, every)


def with_truth(sample: EvalSample, cfg: CompleteConfig) -> EvalSample:
    """The sample with its held-out truth built (a "deferred" one), else as it is."""
    if sample.gt_kind != "deferred":
        return sample
    held, scan = sample.heldout_points, None
    if isinstance(held, TruthScan):
        scan = held.scan()
        held = scan[held.heldout_index]
    return replace(sample, gt=heldout_truth(sample.frame, held, cfg, scan), gt_kind="heldout", heldout_points=None)


def prepare_sample(
    frame: Frame,
    cfg: CompleteConfig,
    truth: bool = True,
    truth_scan: Callable[[], np.ndarray] | None = None,
    recorded: np.ndarray | None = None,
) -> EvalSample:
    """Split the frame's scan into the cheap input and the held-out rest; build the ground truth (with
    `truth=False` a held-out truth is left "deferred": `with_truth` builds it, e.g. off a run's critical path).
    `truth_scan`: gives the same scan deskewed with the ground-truth motion; the held-out returns are taken
    from it (`TruthScan`). `recorded`: the scan as recorded, point for point, where the frame's is deskewed: the
    cheap sensor's returns are chosen on it, so the choice does not depend on a run's motion estimate."""
    if frame.points is None:
        raise DataError(f"frame {frame.index}", "has no LiDAR scan; depth completion needs a range sensor input")
    split = simulate_cheap_sensor(
        frame.points if recorded is None else recorded,
        parse_input(cfg.input),
        frame.index,
        cfg.seed,
        frame.K,
        frame.T_cam_lidar,
        frame.shape,
    )
    if recorded is not None:
        split = replace(split, kept=frame.points[split.kept_index], heldout=frame.points[split.heldout_index])
    sparse = sparse_depth(split.kept, frame.K, frame.T_cam_lidar, frame.shape)
    if frame.depth is not None:
        return EvalSample(frame, sparse, frame.depth, "dense", split.kept)
    if not len(split.heldout):  # the whole scan is the input: nothing held out to score against
        return EvalSample(frame, sparse, np.zeros(frame.shape, np.float32), "none", split.kept)
    heldout = split.heldout if truth_scan is None else TruthScan(truth_scan, split.heldout_index)
    if not truth:
        return EvalSample(frame, sparse, None, "deferred", split.kept, heldout)
    return with_truth(EvalSample(frame, sparse, None, "deferred", split.kept, heldout), cfg)


def warn_empty_input(seq: Sequence, frames: list[int]) -> None:
    """Say which frames had no LiDAR return inside the image (no scan paired with the image, points behind
    the camera, or a calibration that does not match the recording)."""
    warnings.warn(
        f"{seq.path}: {len(frames)} frame(s) have no LiDAR return inside the image ({brief(frames)}); "
        "check which scan each image is paired with (`leovr info`), the scans and the LiDAR-camera "
        "calibration",
        stacklevel=2,
    )


def generator_checkpoint(cfg: CompleteConfig) -> Path:
    """The generator weights a run uses: the configured checkpoint or the shipped one."""
    return Path(cfg.checkpoint or shipped_checkpoint())


def generator_method(cfg: CompleteConfig):
    """A function EvalSample -> (depth, log-sigma) running the configured generator (loaded once)."""
    from leovr.depth.inference import load_generator, predict_at_focal
    from leovr.depth.runtime import for_inference

    model = for_inference(load_generator(generator_checkpoint(cfg)), cfg.generator_runtime)

    def run(sample: EvalSample) -> tuple[np.ndarray, np.ndarray]:
        f = sample.frame
        return predict_at_focal(
            model, f.image, sample.sparse, float(f.K[0, 0]), cfg.generator_focal_px, cfg.prior_edges == "image"
        )

    return run


def depth_method(cfg: CompleteConfig):
    """A function EvalSample -> dense depth for the configured method."""
    if cfg.method != "generator":
        image_edges = cfg.prior_edges == "image"  # only `interp` reads the image
        return lambda sample: complete_depth(sample.sparse, cfg.method, sample.frame.image if image_edges else None)
    run = generator_method(cfg)
    return lambda sample: run(sample)[0]


def frame_indices(n: int, cfg: CompleteConfig) -> list[int]:
    indices = list(range(n))[cfg.start : cfg.end : cfg.step]
    if not indices:
        raise DataError("frames", f"selection start={cfg.start} end={cfg.end} step={cfg.step} is empty for {n} frames")
    return indices


def ground_truth_note(kind: str, cfg: CompleteConfig) -> str:
    if kind == "dense":
        return "dense ground-truth depth of the sequence"
    if kind == "none":
        return "none (the whole scan is the input, no points held out)"
    return (
        f"held-out LiDAR points; each dropped when a return within a {PARALLAX_WINDOW}x{PARALLAX_WINDOW} "
        f"window is nearer by more than {PARALLAX_REL:.0%} (LiDAR-camera parallax filter)"
    )


@single_threaded_blas
def run_completion(
    seq: Sequence,
    cfg: CompleteConfig,
    out: Path | None = None,
    resume: bool = False,
    progress: bool = True,
) -> dict:
    """Complete every selected frame; write `out/depth/NNNNNN.png` and `out/metrics.json` when `out` is set.

    Frames are scored from the arrays computed here; with `resume`, frames whose PNG already exists
    are read back at the folder's recorded scale (1/256 m steps) instead of recomputed. Returns the
    metrics dictionary.
    """
    if not seq.has_lidar:
        raise DataError(seq.path, "sequence has no LiDAR; depth completion needs a range sensor input")
    complete = depth_method(cfg)
    acc = DepthMetricAccumulator(cfg.bins)
    times: list[float] = []
    kinds: set[str] = set()
    indices = frame_indices(len(seq), cfg)
    empty: list[int] = []  # frames whose input has no return inside the image
    names = seq.frame_numbers()
    if out is not None:
        checkpoint = generator_checkpoint(cfg) if cfg.method == "generator" else None
        start_run(
            out,
            "complete",
            run_identity("complete", cfg.model_dump(), [seq.path], checkpoint),
            resume,
            method=cfg.method,
            input=cfg.input,
            sequence=str(Path(seq.path).resolve()),
            frame_numbers=names,
        )
    for i in tqdm(indices, desc=f"complete {cfg.method}/{cfg.input}", unit="frame", disable=not progress):
        sample = prepare_sample(seq[i], cfg)
        kinds.add(sample.gt_kind)
        png = out / "depth" / png_name(names, sample.frame.index) if out is not None else None
        if resume and png is not None and png.is_file():
            pred = read_run_depth(out, "depth", sample.frame.index, sample.frame.shape)
        else:
            t0 = time.perf_counter()
            pred = complete(sample)
            times.append(time.perf_counter() - t0)
            if png is not None:
                write_depth_png(png, pred)
        acc.add(pred, sample.gt)
        if not (sample.sparse > 0).any():
            empty.append(sample.frame.index)
    if empty:
        warn_empty_input(seq, empty)
    metrics = {
        "sequence": str(Path(seq.path).resolve()),
        "reader": seq.name,
        "method": cfg.method,
        "input": cfg.input,
        "frames": len(indices),
        "ground_truth": "; ".join(ground_truth_note(k, cfg) for k in sorted(kinds)),
        "ms_per_frame": float(np.mean(times) * 1000.0) if times else None,
        **acc.result(),
    }
    if out is not None:
        write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return metrics
