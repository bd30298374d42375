"""Development runs for the photometric masks on the `traffic` scenario: train on the traffic recipe's
training sequences with the bench's schedule, score on its validation sequence (seed 2000), never on
the test seeds that `leovr bench selfsup` reports.

    .venv/bin/python tools/traffic_mask_dev.py NAME [--set rigid_mask=false --set auto_mask=false] [--epochs 24]

Runs go to runs/traffic_mask_dev/NAME (resumed with the same settings); the network-free
initialisation graph pass is shared between runs.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import yaml

from leovr.bench.selfsup import base_config, pick_sequences, score, train_run
from leovr.config import BenchSelfSupConfig, CompleteConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator
from leovr.sim.dataset import RECIPES, make_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a selfsup config field (YAML value)")
    ap.add_argument("--epochs", type=int, default=24)
    ap.add_argument("--runs", type=Path, default=Path("runs/traffic_mask_dev"))
    args = ap.parse_args()
    bench = BenchSelfSupConfig()
    root = make_dataset(RECIPES["traffic"], progress=False)
    train = pick_sequences(root, "train", bench, bench.traffic_sequences, ["traffic"])
    val = [open_sequence(p) for p in pick_sequences(root, "val", bench, 1, ["traffic"])]
    overrides = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.set)}
    cfg = base_config(bench, args.epochs, **overrides)
    run = args.runs / args.name
    t0 = time.time()
    train_run(cfg, train, run, progress=False, share_init=args.runs / "_init" if (args.runs / "_init").is_dir() else None)
    if not (args.runs / "_init").is_dir():
        shutil.copytree(run / "graph" / "init", args.runs / "_init")
    metrics = score(load_generator(run / "generator.pt"), val, "full", bench.train_focal_px, list(CompleteConfig().bins))
    print(json.dumps({"name": args.name, "overrides": overrides, "epochs": args.epochs, **metrics,
                      "minutes": round((time.time() - t0) / 60, 1)}), flush=True)


if __name__ == "__main__":
    main()
