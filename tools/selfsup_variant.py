"""One self-supervised variant, initialisation stage only, on the `bench selfsup` training sequences,
scored on its test sequences: a quick way to compare loss settings (about 1.6 min for 8 epochs).

    .venv/bin/python tools/selfsup_variant.py NAME [--set target_loss=l2 --set weight_feature=0] [--epochs 8]

Runs go to runs/selfsup_variants/NAME (resumed when started again with the same settings, else
started again); the network-free initialisation graph pass is copied from the bench's work folder
when it is there.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import yaml

from leovr.bench.selfsup import base_config, pick_sequences, score, train_run
from leovr.config import BenchSelfSupConfig, CompleteConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator
from leovr.sim.dataset import default_root


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a selfsup config field (YAML value)")
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--runs", type=Path, default=Path("runs/selfsup_variants"))
    ap.add_argument("--shared-init", type=Path, default=Path("runs/bench_selfsup_work/selfsup/graph/init"))
    args = ap.parse_args()
    bench = BenchSelfSupConfig()
    root = Path(bench.dataset) if bench.dataset else default_root() / "default"
    train = pick_sequences(root, "train", bench, bench.train_sequences)
    tests = [open_sequence(p) for p in pick_sequences(root, "test", bench, bench.test_sequences)]
    overrides = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in args.set)}
    cfg = base_config(bench, args.epochs, init_fraction=1.0, **overrides)
    run = args.runs / args.name
    t0 = time.time()
    train_run(cfg, train, run, progress=False, share_init=args.shared_init)
    metrics = score(load_generator(run / "generator.pt"), tests, "full", bench.train_focal_px, list(CompleteConfig().bins))
    print(json.dumps({"name": args.name, "overrides": overrides, "epochs": args.epochs, **metrics,
                      "minutes": round((time.time() - t0) / 60, 1)}))


if __name__ == "__main__":
    main()
