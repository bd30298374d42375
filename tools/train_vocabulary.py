#!/usr/bin/env python3
"""Train the ORB bag-of-words vocabulary shipped as odometry/loop/vocabulary.npz, on simulator training
frames only (never the validation or test seeds, never the shared real clips that the benchmarks
score), with a JSON note of how it was made. `--with-real` adds the shared KITTI clips, which then
count as seen data for loop closure.

    .venv/bin/python tools/train_vocabulary.py [--frames-per-seq 10] [--k 10] [--levels 4] [--with-real]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from leovr.data import open_sequence
from leovr.data.io import write_text
from leovr.depth.dataset import split_entries
from leovr.paths import kitti_odometry_dir, kitti_raw_dir, shipped_vocabulary
from leovr.sim.dataset import default_root
from odometry.features import detect
from odometry.loop.vocabulary import Vocabulary


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--dataset", type=Path, default=default_root() / "default")
    ap.add_argument("--frames-per-seq", type=int, default=10)
    ap.add_argument("--k", type=int, default=10)
    ap.add_argument("--levels", type=int, default=4)
    ap.add_argument("--with-real", action="store_true", help="also the shared KITTI clips (seen data)")
    ap.add_argument("--out", type=Path, default=shipped_vocabulary())
    args = ap.parse_args()
    paths = [e["path"] for e in split_entries(args.dataset, "train") if e["light"] == "day"]
    if args.with_real:
        paths += [p for p in (kitti_raw_dir(), kitti_odometry_dir()) if p.exists()]
    docs = []
    for p in paths:
        seq = open_sequence(p)
        for i in np.linspace(0, len(seq) - 1, args.frames_per_seq).astype(int):
            docs.append(detect(seq[int(i)].image).desc)
    desc = np.concatenate([d for d in docs if len(d)])
    t0 = time.time()
    voc = Vocabulary.train(desc, args.k, args.levels, seed=0, docs=docs)
    voc.save(args.out)
    note = {
        "command": "tools/train_vocabulary.py "
        + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if k not in ("out", "with_real"))
        + (" --with-real" if args.with_real else ""),
        "real_clips_seen": bool(args.with_real),
        "sources": [str(p) for p in paths],
        "images": len(docs),
        "descriptors": int(len(desc)),
        "k": args.k,
        "levels": args.levels,
        "words": voc.words,
        "train_s": round(time.time() - t0, 1),
    }
    write_text(args.out.with_suffix(".json"), json.dumps(note, indent=2) + "\n")
    print(json.dumps(note, indent=2))


if __name__ == "__main__":
    main()
