"""The KITTI part of `leovr bench selfsup`: per shared KITTI raw clip and cheap input, a cold start and the shipped
checkpoint fine-tuned, both self-supervised on the clip's first frames, scored with the classical prior and the
shipped checkpoint on held-out LiDAR beams of its last frames."""

from __future__ import annotations

from pathlib import Path

from leovr.bench.config import BenchSelfSupConfig
from leovr.bench.selfsup_models import SHIPPED_FOCAL_PX, held_out_metrics, score, train_run, untrained_generator
from leovr.config import SelfSupConfig
from leovr.data import open_sequence
from leovr.data.sequence import Sequence, SequenceView
from leovr.depth.inference import load_generator
from leovr.depth.fills import complete_depth
from leovr.depth.network import CHANNELS
from leovr.paths import kitti_raw_clips, shared_data_dir, shipped_checkpoint


def kitti_split(n: int, test_share: float) -> tuple[list[int], list[int]]:
    """A clip's training frames (the first) and held-out frames (the last `test_share`, at least one each)."""
    n_test = min(n - 1, max(1, int(round(n * test_share))))
    return list(range(n - n_test)), list(range(n - n_test, n))


def score_prior(seqs: list[Sequence], input_name: str, bins: list[float]) -> dict:
    """The generator's classical prior (image-guided interpolation, leovr.depth.prior) at full resolution."""
    return held_out_metrics(seqs, input_name, bins, lambda s, image: complete_depth(s.sparse, "interp", image))


def kitti_runs(cfg: BenchSelfSupConfig, base: SelfSupConfig, work: Path, quick: bool, progress: bool, bins) -> dict:
    """Per shared KITTI raw clip and cheap input: the classical prior, the shipped checkpoint, a cold start
    (self-supervised from the untrained network, which returns the prior) and the shipped checkpoint
    fine-tuned self-supervised, each trained on the clip's first frames and every model scored on
    held-out beams of its last frames, which no run trained on; the trained models also on the other
    clips' held-out frames (`other_clips`)."""
    clips = [shared_data_dir() / c for c in cfg.kitti_clips] if cfg.kitti_clips is not None else kitti_raw_clips()
    clips = [c for c in clips if c.exists()]
    tests, trained, out = {}, {}, {}
    for path in clips:
        seq = open_sequence(path)
        train, held = kitti_split(len(seq), cfg.kitti_test_share)
        tests[path.name] = [SequenceView(seq, held)]
        for inp in cfg.kitti_inputs:
            cold, fine = kitti_configs(cfg, base, inp, len(train), quick)
            run = work / "kitti" / f"{path.name}_{inp}"
            cold_ck, cold_min = train_run(cold, [path], run / "cold_start", progress)
            fine_ck, fine_min = train_run(fine, [path], run / "fine_tuned", progress)
            trained[path.name, inp] = {"cold_start": cold_ck, "fine_tuned": fine_ck}
            out.setdefault(path.name, {})[inp] = {
                "train_frames": [train[0], train[-1] + 1],
                "test_frames": [held[0], held[-1] + 1],
                "epochs": {"cold_start": cold.epochs, "fine_tuned": fine.epochs},
                "train_minutes": {"cold_start": round(cold_min, 2), "fine_tuned": round(fine_min, 2)},
                "prior": score_prior(tests[path.name], inp, bins),
                "untrained": score(untrained_generator(cold), tests[path.name], inp, SHIPPED_FOCAL_PX, bins),
            }
    shipped = load_generator(shipped_checkpoint())
    models = {run: {name: load_generator(ck) for name, ck in paths.items()} for run, paths in trained.items()}
    for (clip, inp), by_name in models.items():
        entry = out[clip][inp]
        entry["shipped"] = score(shipped, tests[clip], inp, SHIPPED_FOCAL_PX, bins)
        for name, model in by_name.items():
            entry[name] = score(model, tests[clip], inp, SHIPPED_FOCAL_PX, bins)
    for (clip, inp), by_name in models.items():  # the shipped checkpoint's figure on each clip is scored above
        out[clip][inp]["other_clips"] = {
            other: {
                "shipped": out[other][inp]["shipped"]["mae_m"],
                **{name: score(model, test, inp, SHIPPED_FOCAL_PX, bins)["mae_m"] for name, model in by_name.items()},
            }
            for other, test in tests.items()
            if other != clip
        }
    return out


def kitti_configs(
    cfg: BenchSelfSupConfig, base: SelfSupConfig, inp: str, n_train: int, quick: bool
) -> tuple[SelfSupConfig, SelfSupConfig]:
    """The cold start's and the fine-tuning's settings on a clip's `n_train` first frames. Both run at the shipped
    generator's focal length, so that all the models see the same pixels; the learning rate halves four times over
    a run, as in the paper's 24 epochs halved every 6."""
    epochs = cfg.quick_epochs if quick else cfg.kitti_epochs
    cold = base.model_copy(
        update={
            "input": inp,
            "max_frames": n_train,
            "epochs": epochs,
            "refresh_every": cfg.kitti_refresh_every,
            "lr_step_epochs": max(1, epochs // 4),
            "train_focal_px": SHIPPED_FOCAL_PX,
            "channels": list(CHANNELS),
        }
    )
    fine_epochs = cfg.quick_epochs if quick else cfg.kitti_fine_tune_epochs
    fine = cold.model_copy(
        update={
            "epochs": fine_epochs,
            "lr": cfg.kitti_fine_tune_lr,
            "lr_step_epochs": max(1, fine_epochs // 4),
            "init_checkpoint": str(shipped_checkpoint()),
        }
    )
    return cold, fine
