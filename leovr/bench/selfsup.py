"""`leovr bench selfsup`: cold-start self-supervised training (LeoVR Sec. V-B2, V-D2/3) on simulator
`dynamic` and `city_loop` training sequences, scored against ground truth on test sequences:
untrained network, self-supervised (full), without the masks, without L_f and L_r, and a
supervised reference trained on the same frames with the same schedule and network. On the `traffic`
scenario (movers along the epipolar lines): full mask, eq. 19 alone and no mask, and each mask test's
precision / recall against the moving masks (`selfsup.mask_quality`). Then each shared KITTI raw clip
and cheap input: a cold start and the shipped checkpoint fine-tuned, both self-supervised on the clip's
first frames, scored with the classical prior and the shipped checkpoint on held-out LiDAR beams of its
last frames.

Runs live in `<out stem>_work/` next to the JSON and resume when the bench is started again."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from leovr.bench.common import write_bench
from leovr.bench.config import BenchSelfSupConfig
from leovr.config import CompleteConfig, SelfSupConfig
from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.data.sequence import Sequence, SequenceView
from leovr.depth.dataset import split_entries
from leovr.depth.inference import forward_padded, load_generator, predict_at_focal
from leovr.depth.fills import complete_depth
from leovr.depth.network import CHANNELS, DepthGenerator
from leovr.depth.train import depth_loss, optimiser
from leovr.depth.train_state import config_changes, generator_config, save_generator
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.paths import kitti_raw_clips, shared_data_dir, shipped_checkpoint
from leovr.pipeline.completion import prepare_sample
from leovr.pipeline.refine import run_refine
from leovr.sim.dataset import RECIPES, Recipe, default_root, make_dataset
from selfsup.mask_quality import VARIANTS, score_masks
from selfsup.supervision import train_frames
from selfsup.trainer import train_selfsup

SHIPPED_FOCAL_PX = 260.0  # the shipped generator's training focal length (the simulator camera's)
NO_MASKS = {"flow_mask": False, "rigid_mask": False, "depth_mask": False, "auto_mask": False}  # the "no mask" variants
# --quick: one short sequence per scenario in each split, rendered on demand (a fresh clone has no dataset)
QUICK_RECIPE = Recipe(
    "selfsup_quick", {"train": 3, "test": 3}, ("mid40",), ("day",), 12, ("dynamic", "city_loop", "traffic")
)


def pick_sequences(
    root: Path, split: str, cfg: BenchSelfSupConfig, per_scenario: int, scenarios: list[str] | None = None
) -> list[Path]:
    """`per_scenario` sequences of each scenario with the bench's LiDAR, day before night, by seed."""
    entries = [e for e in split_entries(root, split) if e["lidar"] == cfg.lidar]
    out = []
    for scenario in scenarios or cfg.scenarios:
        pool = sorted((e for e in entries if e["scenario"] == scenario), key=lambda e: (e["light"] != "day", e["seed"]))
        out += [e["path"] for e in pool[:per_scenario]]
    return out


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
                (
                    torch.from_numpy(f.image).permute(2, 0, 1).float() / 255.0,
                    torch.from_numpy(f.sparse)[None],
                    torch.from_numpy(gt.astype(np.float32))[None],
                )
            )
    model = DepthGenerator(generator_config(cfg))
    opt, sched = optimiser(model.depth_parameters(), cfg)
    for epoch in tqdm(range(cfg.epochs), desc="supervised reference", unit="epoch", disable=not progress):
        model.train()
        order = torch.randperm(len(samples), generator=torch.Generator().manual_seed(cfg.seed * 1000 + epoch))
        for k in range(0, len(order), cfg.batch_size):
            img, sp, gt = (torch.stack(x) for x in zip(*(samples[int(j)] for j in order[k : k + cfg.batch_size])))
            depth, _ = forward_padded(model, img, sp)
            loss = depth_loss(depth, gt, "l1")
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    save_generator(final, model, cfg, mode="supervised")
    _minutes(out, (time.time() - t0) / 60.0)
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
            return done, _minutes(run)
    if share_init is not None and share_init.is_dir() and not (run / "graph" / "init").exists():
        # the initialisation pass uses no network: same for every run
        shutil.copytree(share_init, run / "graph" / "init")
    train_selfsup(cfg, sequences, run, run_refine, resume=last.is_file(), progress=progress, oracle_masks=oracle_masks)
    return done, _minutes(run, (time.time() - t0) / 60.0)


def _minutes(run: Path, add: float = 0.0) -> float:
    """Training minutes of a run, summed over interrupted and resumed invocations."""
    path = run / "train_minutes.json"
    total = (json.loads(path.read_text())["minutes"] if path.is_file() else 0.0) + add
    if add:
        write_text(path, json.dumps({"minutes": round(total, 2)}) + "\n")
    return total


def datasets(cfg: BenchSelfSupConfig, quick: bool, progress: bool) -> tuple[Path | None, Path | None]:
    """(root of the dynamic / city_loop sequences, of the traffic sequences), None where no part in `cfg.parts`
    reads it (the KITTI part reads neither). --quick renders its own small set (one short sequence per scenario and
    split): it runs on a fresh clone; else the default recipe (tools/make_dataset.py), the traffic one rendered."""
    synthetic, traffic = "synthetic" in cfg.parts, "traffic" in cfg.parts
    if quick and (synthetic or traffic):
        root = make_dataset(QUICK_RECIPE, Path(cfg.dataset) if cfg.dataset else None, progress=progress)
        return root, root
    root = (Path(cfg.dataset) if cfg.dataset else default_root() / "default") if synthetic else None
    return root, make_dataset(RECIPES["traffic"], progress=progress) if traffic else None


def score_paths(checkpoint: Path, tests: list[Sequence], cfg: BenchSelfSupConfig, bins: list[float]) -> dict:
    return score(load_generator(checkpoint), tests, "full", cfg.train_focal_px, bins)


def run_selfsup_bench(out: Path, cfg: BenchSelfSupConfig, quick: bool = False, progress: bool = True) -> dict:
    started = time.time()
    work = Path(out).with_name(Path(out).stem + "_work")
    root, traffic_root = datasets(cfg, quick, progress)
    train = pick_sequences(root, "train", cfg, 1 if quick else cfg.train_sequences) if root else []
    test_paths = pick_sequences(root, "test", cfg, 1 if quick else cfg.test_sequences) if root else []
    shorten = (lambda s: SequenceView(s, list(range(min(len(s), cfg.quick_frames))))) if quick else (lambda s: s)
    epochs = cfg.quick_epochs if quick else cfg.epochs
    base = base_config(cfg, epochs, cfg.quick_frames if quick else None)
    bins = list(CompleteConfig().bins)
    results: dict = {"train_minutes": {}}
    traffic_body: dict = {}
    if "synthetic" in cfg.parts:
        results.update(
            synthetic_runs(
                cfg, base, train, [shorten(open_sequence(p)) for p in test_paths], test_paths, work, progress, bins
            )
        )
    if "traffic" in cfg.parts:
        results["traffic_only"], traffic_body = traffic_runs(
            cfg, base, traffic_root, work, quick, shorten, progress, bins
        )
        results["mask_quality"] = traffic_body.pop("mask_quality")
        results["mask_quality_refine"] = traffic_body.pop("mask_quality_refine")
        results["train_minutes"].update(traffic_body.pop("train_minutes"))
    if "kitti" in cfg.parts:
        results["kitti"] = kitti_runs(cfg, base, work, quick, progress, bins)
    body = {
        "quick": quick,
        "parts": cfg.parts,
        "train_sequences": [str(p.relative_to(root)) for p in train],  # empty without the synthetic part
        "test_sequences": [str(p.relative_to(root)) for p in test_paths],
        **traffic_body,
        "epochs": epochs,
        "train_focal_px": cfg.train_focal_px,
        "lr": cfg.lr,
        "batch_size": cfg.batch_size,
        "loop_closure_note": LOOP_NOTE,
        "results": results,
    }
    return write_bench(out, "selfsup", body, started)


def synthetic_runs(
    cfg: BenchSelfSupConfig,
    base: SelfSupConfig,
    train: list[Path],
    tests: list[Sequence],
    test_paths: list[Path],
    work: Path,
    progress: bool,
    bins: list[float],
) -> dict:
    """dynamic + city_loop: self-supervised (full masks), no masks, no L_f / L_r, supervised reference."""
    variants = {
        "selfsup": base,
        "selfsup_nomask": base.model_copy(update=NO_MASKS),
        "selfsup_no_lf_lr": base.model_copy(update={"weight_feature": 0.0, "weight_refined": 0.0}),
    }
    minutes, checkpoints = {}, {}
    for name, vcfg in variants.items():
        share = None if name == "selfsup" else work / "selfsup" / "graph" / "init"
        checkpoints[name], minutes[name] = train_run(vcfg, train, work / name, progress, share)
    checkpoints["supervised"] = train_supervised_reference(base, train, work / "supervised", progress)
    minutes["supervised"] = _minutes(work / "supervised")
    synthetic = {"untrained": score(untrained_generator(base), tests, "full", cfg.train_focal_px, bins)}
    for name, ck in checkpoints.items():
        synthetic[name] = score_paths(ck, tests, cfg, bins)
    results: dict = {f"{k}_mae_m": v["mae_m"] for k, v in synthetic.items()}
    results["train_minutes"] = {k: round(v, 2) for k, v in minutes.items()}
    results["synthetic_metrics"] = synthetic
    results["selfsup_over_supervised"] = synthetic["selfsup"]["mae_m"] / synthetic["supervised"]["mae_m"]
    results["mask_gain"] = 1.0 - synthetic["selfsup"]["mae_m"] / synthetic["selfsup_nomask"]["mae_m"]
    dyn = [t for t, p in zip(tests, test_paths) if "dynamic" in p.name]
    if dyn:
        results["dynamic_only"] = {
            k: score_paths(checkpoints[k], dyn, cfg, bins)["mae_m"] for k in ("selfsup", "selfsup_nomask")
        }
    return results


LOOP_NOTE = (
    "The pose-quality loop closure (Sec. IV-B) runs in every graph pass but cannot act here: each simulator "
    "sequence is 40 frames (4 s, about 33 m at 30 km/h) and never revisits a place, and the city loop "
    "closes only after about 240 m (29 s). leovr bench loop measures loop closure on full laps instead."
)


def traffic_runs(
    cfg: BenchSelfSupConfig,
    base: SelfSupConfig,
    root: Path,
    work: Path,
    quick: bool,
    shorten,
    progress: bool,
    bins: list[float],
) -> tuple[dict, dict]:
    """The masks on the `traffic` scenario: the full mask (eq. 19 + rigid-flow test + auto-mask), eq. 19
    alone and no mask, each trained on the traffic training sequences and scored on its test
    sequences; then each mask test scored against the moving masks of the test sequences.

    `selfsup_oracle_mask` is a bound, not a method: no mask but the simulator's true moving mask (what
    a perfect mover mask could gain over no mask)."""
    train = pick_sequences(root, "train", cfg, 1 if quick else cfg.traffic_sequences, ["traffic"])
    test_paths = pick_sequences(root, "test", cfg, 1 if quick else 2, ["traffic"])
    tests = [shorten(open_sequence(p)) for p in test_paths]
    runs = {
        "selfsup": base,
        "selfsup_nomask": base.model_copy(update=NO_MASKS),
        "selfsup_eq19_only": base.model_copy(update={"rigid_mask": False, "depth_mask": False, "auto_mask": False}),
        "selfsup_oracle_mask": base.model_copy(update=NO_MASKS),
    }
    maes, minutes, checkpoints = {}, {}, {}
    for name, vcfg in runs.items():
        share = None if name == "selfsup" else work / "traffic_selfsup" / "graph" / "init"
        checkpoints[name], minutes[f"traffic_{name}"] = train_run(
            vcfg, train, work / f"traffic_{name}", progress, share, oracle_masks=name == "selfsup_oracle_mask"
        )
        maes[name] = score_paths(checkpoints[name], tests, cfg, bins)["mae_m"]
    maes["mask_gain"] = 1.0 - maes["selfsup"] / maes["selfsup_nomask"]
    maes["eq19_gain"] = 1.0 - maes["selfsup_eq19_only"] / maes["selfsup_nomask"]
    maes["oracle_mask_gain"] = 1.0 - maes["selfsup_oracle_mask"] / maes["selfsup_nomask"]
    model = load_generator(checkpoints["selfsup"])
    quality = {}
    for stage, ck in (("mask_quality", None), ("mask_quality_refine", checkpoints["selfsup"])):
        per_seq = [
            score_masks(t, base, work / stage / p.name, run_refine, model, checkpoint=ck)
            for t, p in zip(tests, test_paths)
        ]
        quality[stage] = {
            v: {
                k: float(np.mean([q["variants"][v][k] for q in per_seq]))
                for k in ("precision", "recall", "dropped_share")
            }
            for v in VARIANTS
        }
        for key in ("moving_share", "moving_with_depth"):
            quality[stage][key] = float(np.mean([q[key] for q in per_seq]))
    body = {
        "traffic_train_sequences": [str(p.relative_to(root)) for p in train],
        "traffic_test_sequences": [str(p.relative_to(root)) for p in test_paths],
        "train_minutes": {k: round(v, 2) for k, v in minutes.items()},
        **quality,
    }
    return maes, body


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
