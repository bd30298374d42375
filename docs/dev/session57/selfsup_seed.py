"""Session 57 (issue 19): the bench selfsup synthetic model, default masks or none (`default` / `nomask`), with
training seed 1 (the bench trains seed 0), scored on the bench's test sequences: the spread of one setting, not a
choice (nothing is tuned on it).

    .venv/bin/python docs/dev/session57/selfsup_seed.py default|nomask
"""
import json, sys, time
from pathlib import Path
from leovr.bench.selfsup import base_config, pick_sequences, score, train_run, NO_MASKS
from leovr.config import BenchSelfSupConfig, CompleteConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator
from leovr.sim.dataset import default_root
name = sys.argv[1]
bench = BenchSelfSupConfig()
root = default_root() / "default"
train = pick_sequences(root, "train", bench, bench.train_sequences)
tests = [open_sequence(p) for p in pick_sequences(root, "test", bench, bench.test_sequences)]
cfg = base_config(bench, bench.epochs, seed=1, **(NO_MASKS if name == "nomask" else {}))
run = Path("runs/s57/seed1") / name
t0 = time.time()
train_run(cfg, train, run, progress=False, share_init=None)
m = score(load_generator(run / "generator.pt"), tests, "full", bench.train_focal_px, list(CompleteConfig().bins))
print(json.dumps({"name": name, "seed": 1, **m, "minutes": round((time.time() - t0) / 60, 1)}), flush=True)
