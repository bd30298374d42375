"""`leovr bench real`: depth on each real KITTI raw drive against the classical fills, on the same
pixels, and leovr's trajectory against KISS-ICP's on the same input where the drive has ground-truth poses.

Each cheap input (VLP-16-like, Mid-40-like) is simulated from the drive's HDL-64 scan; the held-out
returns, parallax-filtered, are the ground truth. Methods, all scored on the very same pixels:
`nearest` and `ipbasic` (classical fills; with a cone LiDAR also `nearest_accumulated` and `ipbasic_accumulated`,
the same frames' returns placed with KISS-ICP's poses and filled), `interp` (the generator's classical prior alone),
`generator` and `refined` (the shipped generator and the graph over it), every frame scored (`shipped_<input>`);
with `causal` each input also runs in refine's causal mode (`causal_<input>`: every output from its frame and
earlier ones, the accumulated fills too; the run's own held-out pixels). Refinement runs over the whole clip (it
reads no ground truth); only the scored frames differ. Each clip is reported alone and all clips pooled
(every scored pixel of every clip), with whether it is development data (under ../shared/data). Runs are
kept in `<stem>_work/` and resumed when the settings and the code (the checkout's commit, no uncommitted change)
are unchanged.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from pathlib import Path

import numpy as np

from leovr.bench.common import depth_entry, git_commit, write_bench
from leovr.bench.config import BenchRealConfig
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.data.oxts import REFERENCE_NOTE
from leovr.depth.fills import complete_depth
from leovr.errors import DataError
from leovr.geometry import invert_T
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.pipeline.completion import ground_truth_note
from leovr.pipeline.refine import run_refine
from leovr.pipeline.refine_input import completion_config, frame_sample
from leovr.pipeline.refine_metrics import FrameScore
from leovr.pipeline.refine_input import TRUTH_DESKEW_NOTE

# generator: the shipped generator as it ran in refine (with earlier scans for a cone LiDAR, Mid-40-like);
# generator_frame: on the frame's own input alone (only where earlier scans were added)
# nearest / ipbasic_accumulated: the same frames' returns placed with KISS-ICP's poses, then filled (cone LiDAR only)
METHODS = (
    "nearest",
    "ipbasic",
    "nearest_accumulated",
    "ipbasic_accumulated",
    "interp",
    "generator",
    "generator_frame",
    "refined",
)


def prepared_work(work: Path, settings: dict) -> None:
    """Keep `work` for a resumed run with the same settings and code; start it afresh otherwise. A run of other code
    is not resumed (its finished frames would stand in the results unchanged): the code is the checkout's commit,
    and a checkout with uncommitted changes always starts afresh."""
    code = git_commit()
    settings = {**settings, "code": code if code and not code.endswith("-dirty") else f"uncommitted {time.time()}"}
    stamp = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
    marker = work / "settings.json"
    if marker.is_file() and json.loads(marker.read_text()).get("hash") != stamp:
        shutil.rmtree(work)
    work.mkdir(parents=True, exist_ok=True)
    write_text(marker, json.dumps({"hash": stamp, "settings": settings}, indent=2) + "\n")


def interp_scores(seq, rcfg: RefineConfig, frames: dict[int, FrameScore]) -> None:
    """Add the classical prior alone (`interp`) to each frame's scores, on the same pixels."""
    ccfg = completion_config(rcfg)
    for i, fs in frames.items():
        s = frame_sample(seq, i, ccfg)
        fs.add("interp", complete_depth(s.sparse, "interp", s.frame.image if ccfg.prior_edges == "image" else None))


def pooled(sets: list[tuple[dict[int, FrameScore], list[int]]], bins: list[float]) -> dict:
    """Metrics per method pooled over every scored pixel of the frames `indices` of each (frames, indices) set:
    one clip's, or every clip's (no timing: runs differ per method)."""
    out = {}
    for method in METHODS:
        acc = DepthMetricAccumulator(bins)
        for frames, indices in sets:
            for i in indices:
                if i in frames and method in frames[i].pred:
                    acc.add(frames[i].pred[method], frames[i].gt)
        if acc.empty:
            continue
        out[method] = depth_entry(acc.result())
        out[method].pop("ms_per_frame")
    return out


def run_real_bench(out: Path, cfg: BenchRealConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    from leovr.paths import kitti_raw_clips, shared_data_dir

    clips = [Path(c) for c in cfg.clips] if cfg.clips else kitti_raw_clips()
    if not clips:
        raise DataError(
            shared_data_dir(), "no KITTI raw drive found (set LEOVR_SHARED_DATA or `real.clips` in the bench config)"
        )
    for clip in clips:
        if not clip.exists():
            raise DataError(clip, "KITTI raw drive not found")
    settings = {**cfg.model_dump(), "quick": quick, "clips": [str(c) for c in clips]}
    work = Path(out).with_name(Path(out).stem + "_work")
    prepared_work(work, settings)
    shared = shared_data_dir().resolve()
    per_clip, notes = {}, set()
    every: dict[str, list[tuple[dict[int, FrameScore], list[int]]]] = {}  # run -> each clip's scored set
    for clip in clips:
        entry, scored = clip_bench(clip, cfg, quick, progress, work / clip.name)
        entry["development"] = shared in clip.resolve().parents
        per_clip[clip.name] = entry
        for key, (frames, indices) in scored.items():
            notes |= {fs.kind for fs in frames.values()}
            every.setdefault(key, []).append((frames, indices))
    pooled_results = {key: pooled(sets, list(RefineConfig().bins)) for key, sets in every.items()}
    body = {
        "quick": quick,
        "clips": per_clip,
        "pooled": {
            "clips": list(per_clip),
            "results": pooled_results,
            "summary": summary_of(pooled_results),
            "trajectory_vs_kiss_icp": {inp: float(np.mean(r)) for inp, r in trajectory_ratios(per_clip).items()},
        },
        "ground_truth": "; ".join(ground_truth_note(k, completion_config(RefineConfig())) for k in sorted(notes))
        + ("; " + TRUTH_DESKEW_NOTE if "heldout" in notes else ""),
        "ground_truth_poses": REFERENCE_NOTE,
    }
    return write_bench(out, "real", body, started)


def gps_fix_ates(seq, run: Path, n: int) -> dict[str, float]:
    """Each written trajectory's ATE (SE(3)-aligned) against the recording's GPS fixes alone, as KITTI's devkit
    reads them, where the reader keeps them (`gps_poses`): the figure users of the devkit compare with."""
    gps = getattr(seq, "gps_poses", None)
    if gps is None:
        return {}
    from leovr.data.kitti_common import read_kitti_poses
    from leovr.eval.trajectory import trajectory_metrics

    ref = invert_T(gps[0]) @ gps[:n]
    files = {"leovr": "poses_kitti.txt", "kiss_icp": "poses_kiss_icp_kitti.txt"}
    files["kiss_icp_no_deskew"] = "poses_kiss_icp_no_deskew_kitti.txt"
    return {
        name: trajectory_metrics(read_kitti_poses(run / f), ref)["ate_m"]
        for name, f in files.items()
        if (run / f).is_file()
    }


def trajectory_entry(metrics: dict, gps_ates: dict[str, float]) -> dict:
    """ATE (whole clip and per stretch of 32 frames; against the GPS fixes alone too, `gps_ates`), RPE, KITTI's
    relative errors and the median step ratio of leovr and the baselines of one refine run, and leovr's ATE
    over KISS-ICP's (the better of its two deskew settings)."""
    keys = (
        "ate_m",
        "ate_lateral_m",
        "ate_vertical_m",
        "ate_forward_m",
        "ate_per_stretch_m",
        "rpe_m",
        "kitti_t_err_pct",
        "kitti_r_err_deg_per_m",
        "kitti_segments",
        "step_ratio_median",
    )
    t = {k: {key: v[key] for key in keys if key in v} for k, v in metrics["trajectory"].items()}
    for name, ate in gps_ates.items():
        if name in t:
            t[name]["ate_gps_fixes_m"] = ate
    kiss = min(v["ate_m"] for k, v in t.items() if k.startswith("kiss_icp"))
    return t | {"leovr_vs_kiss_icp": t["leovr"]["ate_m"] / kiss}


def trajectory_ratios(per_clip: dict) -> dict[str, list[float]]:
    """Per input: leovr's ATE over KISS-ICP's on the same input (the better of its two deskew settings), one
    per clip with ground-truth poses."""
    out: dict[str, list[float]] = {}
    for entry in per_clip.values():
        for inp, t in entry.get("trajectory", {}).items():
            out.setdefault(inp, []).append(t["leovr_vs_kiss_icp"])
    return out


def summary_of(results: dict) -> dict:
    """Each method's MAE over the nearest fill's, and the methods worse than it within 20 m."""
    summary = {}
    for key, r in results.items():
        near = r["nearest"]["mae_m"]
        summary[key] = {f"{m}_vs_nearest": r[m]["mae_m"] / near for m in r if m != "nearest" and r[m]["mae_m"]}
        if "nearest_accumulated" in r:  # the fair yardstick where the refinement sees several frames
            summary[key]["refined_vs_nearest_accumulated"] = r["refined"]["mae_m"] / r["nearest_accumulated"]["mae_m"]
        summary[key]["worse_than_nearest_0_20m"] = [
            m for m in r if (r[m]["bins"].get("0-20") or {}).get("mae_m", 0) > r["nearest"]["bins"]["0-20"]["mae_m"]
        ]
    return summary


def clip_bench(
    clip: Path, cfg: BenchRealConfig, quick: bool, progress: bool, work: Path
) -> tuple[dict, dict[str, tuple[dict[int, FrameScore], list[int]]]]:
    """One drive: its results and summary per run and input, leovr's and KISS-ICP's trajectories where
    it has poses; and each run's frame scores with the frames it scores (to pool)."""
    seq = open_sequence(clip)
    n = min(len(seq), cfg.quick_frames) if quick else len(seq)
    results, trajectory = {}, {}
    scored_sets: dict[str, tuple[dict[int, FrameScore], list[int]]] = {}
    for inp in cfg.inputs:
        base = RefineConfig(input=inp, end=n, window=cfg.window, checkpoint=cfg.checkpoint)
        shipped: dict[int, FrameScore] = {}
        m = run_refine(seq, base, work / f"{inp}_shipped", resume=True, progress=progress, collect=shipped)
        interp_scores(seq, base, shipped)
        if "trajectory" in m:
            trajectory[inp] = trajectory_entry(m, gps_fix_ates(seq, work / f"{inp}_shipped", n))
        if cfg.causal:  # live use: every output from its frame and earlier ones (baselines too)
            live: dict[int, FrameScore] = {}
            mc = run_refine(
                seq,
                base.model_copy(update={"causal": True}),
                work / f"{inp}_causal",
                resume=True,
                progress=progress,
                collect=live,
            )
            results[f"causal_{inp}"] = pooled([(live, list(range(n)))], list(base.bins))
            scored_sets[f"causal_{inp}"] = live, list(range(n))
            if "trajectory" in mc:
                trajectory[f"causal_{inp}"] = trajectory_entry(mc, gps_fix_ates(seq, work / f"{inp}_causal", n))
        results[f"shipped_{inp}"] = pooled([(shipped, list(range(n)))], list(base.bins))
        scored_sets[f"shipped_{inp}"] = shipped, list(range(n))
    entry = {
        "path": str(clip),
        "frames": n,
        "has_poses": seq.has_poses,
        "results": results,
        "summary": summary_of(results),
        "trajectory": trajectory,
    }
    return entry, scored_sets
