#!/usr/bin/env python3
"""Development check of leovr's poses against KISS-ICP in the same run, on development data only
(simulator validation sequences, seeds 2000-2002; never the test seeds or the clips the benchmark
reports). ATE (SE(3) alignment with LiDAR: metric) of leovr and of KISS-ICP alone (the `kiss_icp` baseline).

    .venv/bin/python tools/pose_dev.py [--input full] [--frames N] [--cfg F=V ...] -- SEQ [SEQ ...]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.pipeline.refine import run_refine


def _value(v: str):
    for cast in (int, float):
        try:
            return cast(v)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(v.lower(), v)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--input", default="full")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--cfg", nargs="*", default=[], help="RefineConfig field=value")
    a = ap.parse_args()
    cfg = RefineConfig(input=a.input, **{k: _value(v) for k, v in (s.split("=", 1) for s in a.cfg)})
    ratios = []
    for path in a.sequences:
        seq = open_sequence(path)
        n = min(len(seq), a.frames or len(seq))
        with tempfile.TemporaryDirectory() as tmp:
            m = run_refine(seq, cfg.model_copy(update={"end": n}), Path(tmp), progress=False)
        t = m.get("trajectory", {})
        row = {"sequence": Path(path).name, "frames": n,
               **{k: round(t[k]["ate_m"], 3) for k in ("leovr", "kiss_icp", "mono_vo") if k in t}}
        if "kiss_icp" in t:
            row["ratio"] = round(t["leovr"]["ate_m"] / max(t["kiss_icp"]["ate_m"], 1e-9), 2)
            ratios.append(row["ratio"])
        row["ms"] = {k: round(v["median"]) for k, v in m["timing"]["stats"].items()}
        for method in ("generator", "refined"):
            if method in m.get("depth", {}):
                row[f"{method}_mae"] = round(m["depth"][method]["mae_m"], 3)
        print(json.dumps(row), flush=True)
    if ratios:
        print(json.dumps({"mean_ratio": round(sum(ratios) / len(ratios), 3), "cfg": a.cfg}), flush=True)


if __name__ == "__main__":
    main()
