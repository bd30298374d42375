#!/usr/bin/env python3
"""Copy a trained generator (`best.pt`) into the package as the shipped checkpoint, in half precision
(about 9 MB), with a JSON note of where it came from. Then `tools/calibrate_int8.py` adds the int8
runtime's calibration table (kept here when `best.pt` already has one).

    .venv/bin/python tools/ship_checkpoint.py runs/gen_quick/best.pt --command "leovr train ..."
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from leovr.data.io import atomic_write, write_text
from leovr.paths import shipped_checkpoint


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("best", type=Path)
    ap.add_argument("--command", required=True, help="the exact command that trained it")
    args = ap.parse_args()
    state = torch.load(args.best, map_location="cpu", weights_only=False)
    half = {k: (v.half() if v.is_floating_point() else v) for k, v in state["model"].items()}
    out = shipped_checkpoint()
    shipped = {"model": half, "network": state["network"]}
    if state.get("int8_ranges") is not None:
        shipped["int8_ranges"] = state["int8_ranges"]
    atomic_write(out, lambda tmp: torch.save(shipped, tmp))
    log = args.best.parent / "log.jsonl"
    meta = {
        "trained_with": args.command,
        "config": state.get("config"),
        "epoch": state.get("epoch"),
        "val_mae_m": state.get("val_mae_m"),
        "log": [json.loads(x) for x in log.read_text().splitlines()] if log.is_file() else None,
    }
    write_text(out.with_suffix(".json"), json.dumps(meta, indent=2) + "\n")
    print(f"{out} ({out.stat().st_size / 1e6:.1f} MB)")
    if "int8_ranges" not in shipped:  # the default runtime needs it; without it the network runs in floating point
        print("no int8 calibration table: run .venv/bin/python tools/calibrate_int8.py")


if __name__ == "__main__":
    main()
