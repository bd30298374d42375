"""`leovr bench real`: depth on the real KITTI raw clip against the classical fills, on the same pixels.

Each cheap input (VLP-16-like, Mid-40-like) is simulated from the clip's HDL-64 scan; the held-out
returns, parallax-filtered, are the ground truth. Methods, all scored on the very same pixels:
`nearest` and `ipbasic` (classical fills), `interp` (the generator's classical prior alone),
`generator` and `refined` (the shipped generator and the graph over it), `adapted` and
`adapted_refined` (after `leovr adapt` on the clip's own cheap input). Protocols:
- `inductive`: adapt on frames [0, inductive_train_frames), score the frames after;
- `transductive`: adapt on every frame, using only its cheap input, score every frame (what a user
  does with a recording: adaptation never sees the held-out returns).
Refinement runs over the whole clip in both protocols (it reads no ground truth); only the scored
frames differ. Runs are kept in `<stem>_work/` and resumed when the settings are unchanged.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from pathlib import Path

from leovr.bench.common import depth_entry, write_bench
from leovr.config import AdaptConfig, BenchRealConfig, RefineConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.depth.classical import complete_depth
from leovr.errors import DataError
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.pipeline.completion import ground_truth_note
from leovr.pipeline.refine import FrameScore, completion_config, frame_sample, run_refine

# generator: the shipped generator as it ran in refine (with earlier scans for a cone LiDAR, Mid-40-like);
# generator_frame: on the frame's own input alone (only where earlier scans were added)
METHODS = ("nearest", "ipbasic", "interp", "generator", "generator_frame", "refined", "adapted", "adapted_refined")


def prepared_work(work: Path, settings: dict) -> None:
    """Keep `work` for a resumed run with the same settings; start it afresh otherwise."""
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


def pooled(frames: dict[int, FrameScore], indices: list[int], bins: list[float]) -> dict:
    """Metrics per method pooled over the frames `indices` (no timing: runs differ per method)."""
    out = {}
    for method in METHODS:
        acc = DepthMetricAccumulator(bins)
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
    from leovr.paths import kitti_raw_dir

    clip = Path(cfg.kitti_raw) if cfg.kitti_raw else kitti_raw_dir()
    if not clip.exists():
        raise DataError(clip, "KITTI raw clip not found (set LEOVR_SHARED_DATA or bench_real.kitti_raw)")
    seq = open_sequence(clip)
    n = min(len(seq), cfg.quick_frames) if quick else len(seq)
    split = cfg.quick_train_frames if quick else cfg.inductive_train_frames
    if not 0 < split < n:
        raise DataError(clip, f"{n} frames cannot be split at frame {split} for the inductive protocol")
    epochs = cfg.quick_epochs if quick else cfg.adapt_epochs
    settings = {**cfg.model_dump(), "quick": quick, "frames": n, "clip": str(clip)}
    work = Path(out).with_name(Path(out).stem + "_work")
    prepared_work(work, settings)
    protocols = {"inductive": (split, list(range(split, n))), "transductive": (None, list(range(n)))}
    results, minutes, blends, notes = {}, {}, {}, set()
    for inp in cfg.inputs:
        base = RefineConfig(input=inp, end=n, window=cfg.window, checkpoint=cfg.checkpoint)
        shipped: dict[int, FrameScore] = {}
        run_refine(seq, base, work / f"{inp}_shipped", resume=True, progress=progress, collect=shipped)
        interp_scores(seq, base, shipped)
        notes |= {fs.kind for fs in shipped.values()}
        for protocol, (adapt_end, scored) in protocols.items():
            acfg = AdaptConfig(input=inp, end=adapt_end if adapt_end is not None else n, epochs=epochs,
                               init_checkpoint=cfg.checkpoint, seed=cfg.seed)
            from selfsup.adapt import adapt

            record = adapt([seq], acfg, work / f"{inp}_{protocol}_adapt", resume=True, progress=progress)
            minutes[f"{protocol}_{inp}"] = record["minutes"]
            blends[f"{protocol}_{inp}"] = {"blend": record.get("blend", 1.0),
                                           "val_mae_m_by_blend": record.get("val_mae_m_by_blend")}
            adapted: dict[int, FrameScore] = {}
            ck = work / f"{inp}_{protocol}_adapt" / "generator.pt"
            run_refine(seq, base.model_copy(update={"checkpoint": str(ck)}), work / f"{inp}_{protocol}_refine",
                       resume=True, progress=progress, collect=adapted)
            for i, fs in adapted.items():  # same frames, same input, same held-out pixels
                if i in shipped:
                    shipped[i].pred["adapted"] = fs.pred["generator"]
                    shipped[i].pred["adapted_refined"] = fs.pred["refined"]
            results[f"{protocol}_{inp}"] = pooled(shipped, scored, list(base.bins))
    summary = {}
    for key, r in results.items():
        near = r["nearest"]["mae_m"]
        summary[key] = {f"{m}_vs_nearest": r[m]["mae_m"] / near for m in r if m != "nearest" and r[m]["mae_m"]}
        summary[key]["worse_than_nearest_0_20m"] = [
            m for m in r if (r[m]["bins"].get("0-20") or {}).get("mae_m", 0) > r["nearest"]["bins"]["0-20"]["mae_m"]]
    body = {
        "quick": quick,
        "clip": str(clip),
        "frames": n,
        "protocols": {"inductive": f"adapt on frames 0-{split - 1}, score frames {split}-{n - 1}",
                      "transductive": f"adapt on frames 0-{n - 1} (their cheap input only), score all of them"},
        "ground_truth": "; ".join(ground_truth_note(k, completion_config(RefineConfig())) for k in sorted(notes)),
        "adapt_epochs": epochs,
        "adapt_minutes": minutes,
        "adapt_blend": blends,  # the adapted network's weight against its prior, chosen on validation frames
        "results": results,
        "summary": summary,
    }
    return write_bench(out, "real", body, started)
