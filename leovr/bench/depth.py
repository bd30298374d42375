"""`leovr bench depth`: nearest fill, IP-Basic and the generator on simulator test sequences (seeds never
used for training; each sequence's own Mid-40 or VLP-16 scan as input, dense ground truth) and on the
shared KITTI raw clip (cheap inputs simulated from the HDL-64 scan, held-out points as ground truth).

Besides the baseline's metric keys, the generator reports how well its predicted sigma ranks its
actual errors (Spearman correlation of |error| and log-sigma over ground-truth pixels) and, on the
synthetic sets, its time per 448x256 frame as a ratio to IP-Basic measured in the same run.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr
from tqdm import tqdm

from leovr.bench.common import depth_entry, write_bench
from leovr.bench.config import BenchDepthConfig
from leovr.config import CompleteConfig
from leovr.data import open_sequence
from leovr.data.sequence import Sequence
from leovr.depth.dataset import split_entries
from leovr.errors import DataError
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.pipeline.completion import (
    depth_method,
    generator_method,
    ground_truth_note,
    prepare_sample,
)
from leovr.sim.dataset import Recipe, default_root, make_dataset

QUICK_RECIPE = Recipe("bench_quick", {"test": 1}, ("mid40", "vlp16"), ("day", "night"), 4)
SPEARMAN_SAMPLES = 200_000  # pixels drawn (seeded) for the rank correlation


class MethodScores:
    """Accumulated metrics, time and (for the generator) error/sigma samples of one method on one set."""

    def __init__(self, bins: list[float]) -> None:
        self.acc = DepthMetricAccumulator(bins)
        self.by_light: dict[str, DepthMetricAccumulator] = {}
        self.seconds: list[float] = []
        self.err: list[np.ndarray] = []
        self.sigma: list[np.ndarray] = []
        self.bins = bins

    def add(
        self, pred: np.ndarray, gt: np.ndarray, seconds: float, light: str | None, log_sigma: np.ndarray | None = None
    ) -> None:
        self.acc.add(pred, gt)
        if light is not None:
            self.by_light.setdefault(light, DepthMetricAccumulator(self.bins)).add(pred, gt)
        self.seconds.append(seconds)
        if log_sigma is not None:
            valid = np.isfinite(gt) & (gt > 0)
            self.err.append(np.abs(pred[valid] - gt[valid]).astype(np.float32))
            self.sigma.append(log_sigma[valid].astype(np.float32))

    def entry(self, seed: int) -> dict:
        e = depth_entry({**self.acc.result(), "ms_per_frame": 1000.0 * float(np.mean(self.seconds))})
        if self.by_light:
            e["by_light"] = {
                k: {m: v for m, v in a.result().items() if m in ("mae_m", "rmse_m", "n")}
                for k, a in sorted(self.by_light.items())
            }
        if self.err:
            err, sig = np.concatenate(self.err), np.concatenate(self.sigma)
            if err.size > SPEARMAN_SAMPLES:
                pick = np.random.default_rng(seed).choice(err.size, SPEARMAN_SAMPLES, replace=False)
                err, sig = err[pick], sig[pick]
            rho = spearmanr(err, sig).statistic if err.size > 2 else float("nan")
            e["uncertainty"] = {"spearman_error_sigma": float(rho), "pixels": int(err.size)}
        return e


def score_sequences(
    seqs: list[tuple[Sequence, str | None]],
    input_name: str,
    cfg: BenchDepthConfig,
    step: int,
    desc: str,
    progress: bool = True,
) -> tuple[dict, str]:
    """Run every method on every `step`-th frame of the sequences; returns results per method and the
    ground-truth note. `seqs` pairs each sequence with its lighting (None when unknown)."""
    base = CompleteConfig(
        input=input_name, seed=cfg.seed, checkpoint=cfg.checkpoint, generator_focal_px=cfg.generator_focal_px
    )
    runners = {}
    for m in cfg.methods:
        mcfg = base.model_copy(update={"method": m})
        runners[m] = generator_method(mcfg) if m == "generator" else depth_method(mcfg)
    scores = {m: MethodScores(base.bins) for m in cfg.methods}
    kinds: set[str] = set()
    jobs = [(seq, light, i) for seq, light in seqs for i in range(0, len(seq), step)]
    if jobs:  # warm-up call per method, untimed (first-call allocations and thread start-up)
        first = prepare_sample(jobs[0][0][jobs[0][2]], base)
        for run in runners.values():
            run(first)
    for seq, light, i in tqdm(jobs, desc=desc, unit="frame", disable=not progress):
        sample = prepare_sample(seq[i], base)
        kinds.add(sample.gt_kind)
        for m, run in runners.items():
            t0 = time.perf_counter()
            out = run(sample)
            dt = time.perf_counter() - t0
            pred, log_sigma = out if m == "generator" else (out, None)
            scores[m].add(pred, sample.gt, dt, light, log_sigma)
    note = "; ".join(ground_truth_note(k, base) for k in sorted(kinds))
    return {m: s.entry(cfg.seed) for m, s in scores.items()}, note


def synthetic_sets(cfg: BenchDepthConfig, quick: bool, progress: bool) -> tuple[Path, dict[str, list]]:
    """Test-split sequences per LiDAR model, each with its lighting."""
    if quick:
        root = make_dataset(QUICK_RECIPE, Path(cfg.dataset) if cfg.dataset else None, progress=progress)
    else:
        root = Path(cfg.dataset) if cfg.dataset else default_root() / "default"
    groups: dict[str, list] = {}
    for e in split_entries(root, "test"):
        groups.setdefault(e["lidar"], []).append((open_sequence(e["path"]), e["light"]))
    return root, groups


def run_depth_bench(out: Path, cfg: BenchDepthConfig, quick: bool = False, progress: bool = True) -> dict:
    """Fill `results.synthetic_<lidar>` and `results.kitti_<input>` for every method; write JSON."""
    started = time.time()
    results: dict[str, dict] = {}
    notes: dict[str, str] = {}
    root, groups = synthetic_sets(cfg, quick, progress)
    step = cfg.quick_step if quick else 1
    for lidar in cfg.synthetic_lidars:
        if lidar not in groups:
            raise DataError(root / "manifest.json", f"no {lidar} sequences in the test split")
        results[f"synthetic_{lidar}"], notes["synthetic"] = score_sequences(
            groups[lidar], "full", cfg, 1 if quick else cfg.synthetic_step, f"synthetic {lidar}", progress
        )
    kitti = None
    if cfg.kitti_inputs:
        from leovr.paths import kitti_raw_dir

        kitti = Path(cfg.kitti) if cfg.kitti else kitti_raw_dir()
        if not kitti.exists():
            raise DataError(
                kitti, "KITTI raw clip not found (set LEOVR_SHARED_DATA or `depth.kitti` in the bench config)"
            )
        seq = open_sequence(kitti)
        for inp in cfg.kitti_inputs:
            results[f"kitti_{inp}"], notes["kitti"] = score_sequences(
                [(seq, None)], inp, cfg, step, f"kitti {inp}", progress
            )
    summary = {}
    for key, methods in results.items():
        if "generator" in methods and "ipbasic" in methods:
            g, ipb = methods["generator"], methods["ipbasic"]
            summary[key] = {
                "generator_mae_vs_ipbasic": g["mae_m"] / ipb["mae_m"],
                "generator_time_vs_ipbasic": g["ms_per_frame"] / ipb["ms_per_frame"],
            }
    body = {
        "quick": quick,
        "synthetic_dataset": str(root),
        "synthetic_input": "each test sequence's own LiDAR scan (all of it), 448x256, day and night",
        "kitti_sequence": None if kitti is None else str(kitti),
        "kitti_frames_step": step,
        "generator_focal_px": cfg.generator_focal_px,
        "ground_truth": notes,
        "results": results,
        "summary": summary,
    }
    return write_bench(out, "depth", body, started)
