"""Development runs for the photometric masks on the `traffic` scenario: train on the traffic recipe's
training sequences with the bench's schedule, score on its validation sequence (seed 2000), never on
the test seeds that `leovr bench selfsup` reports. MAE is given on all pixels and split into moving
and static ones (the simulator's moving masks).

    .venv/bin/python tools/traffic_mask_dev.py NAME [--set rigid_mask=false --set auto_mask=false] [--epochs 24]
    .venv/bin/python tools/traffic_mask_dev.py oracle --oracle --set flow_mask=false --set rigid_mask=false --set auto_mask=false

Runs go to runs/traffic_mask_dev/NAME (resumed with the same settings); the network-free
initialisation graph pass is shared between runs. `--oracle` is a bound, not a method: the photometric
mask is the simulator's moving mask (ground truth; `selfsup.trainer.train_selfsup(oracle_masks=True)`), in place of
every configured test.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np
import yaml

from leovr.bench.selfsup import base_config, pick_sequences, score, train_run
from leovr.config import BenchSelfSupConfig, CompleteConfig
from leovr.data import open_sequence
from leovr.data.sequence import Sequence
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.pipeline.completion import prepare_sample
from leovr.sim.dataset import RECIPES, make_dataset


def moving_static_mae(model, seqs: list[Sequence], focal_px: float) -> dict[str, float]:
    """MAE on the moving and on the static ground-truth pixels."""
    errors: dict[str, list[np.ndarray]] = {"moving": [], "static": []}
    for seq in seqs:
        for i in range(len(seq)):
            frame = seq[i]
            s = prepare_sample(frame, CompleteConfig(input="full"))
            depth, _ = predict_at_focal(model, frame.image, s.sparse, float(frame.K[0, 0]), focal_px)
            ok, moving = s.gt > 0, frame.moving_mask.astype(bool)
            errors["moving"].append(np.abs(depth - s.gt)[ok & moving])
            errors["static"].append(np.abs(depth - s.gt)[ok & ~moving])
    return {f"mae_{k}_m": float(np.concatenate(v).mean()) if sum(e.size for e in v) else None for k, v in errors.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a selfsup config field (YAML value)")
    ap.add_argument("--epochs", type=int, default=24)
    ap.add_argument("--runs", type=Path, default=Path("runs/traffic_mask_dev"))
    ap.add_argument("--oracle", action="store_true", help="bound: the simulator's moving masks as the photometric mask")
    args = ap.parse_args()
    bench = BenchSelfSupConfig()
    root = make_dataset(RECIPES["traffic"], progress=False)
    train = pick_sequences(root, "train", bench, bench.traffic_sequences, ["traffic"])
    val = [open_sequence(p) for p in pick_sequences(root, "val", bench, 1, ["traffic"])]
    overrides = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.set)}
    cfg = base_config(bench, args.epochs, **overrides)
    run = args.runs / args.name
    marker = run / "oracle.json"  # --oracle is not part of the config: a run is resumed only the same way
    started = json.loads(marker.read_text())["oracle"] if marker.is_file() else False
    if run.is_dir() and started != args.oracle:
        ap.error(f"{run} was started {'with' if started else 'without'} --oracle; give another NAME")
    run.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps({"oracle": args.oracle}) + "\n")
    t0 = time.time()
    train_run(cfg, train, run, progress=False, share_init=args.runs / "_init" if (args.runs / "_init").is_dir() else None,
              oracle_masks=args.oracle)
    if not (args.runs / "_init").is_dir():
        shutil.copytree(run / "graph" / "init", args.runs / "_init")
    model = load_generator(run / "generator.pt")
    metrics = score(model, val, "full", bench.train_focal_px, list(CompleteConfig().bins))
    metrics.update(moving_static_mae(model, val, bench.train_focal_px))
    print(json.dumps({"name": args.name, "oracle": args.oracle, "overrides": overrides, "epochs": args.epochs, **metrics,
                      "minutes": round((time.time() - t0) / 60, 1)}), flush=True)


if __name__ == "__main__":
    main()
