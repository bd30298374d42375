#!/usr/bin/env python3
"""Generate the simulator dataset splits (see docs/datasets.md).

.venv/bin/python tools/make_dataset.py [--recipe default|tiny|traffic] [--root DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from leovr.sim.dataset import RECIPES, default_root, make_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recipe", default="default", choices=sorted(RECIPES))
    ap.add_argument("--root", type=Path, default=None, help=f"cache folder (default {default_root()})")
    args = ap.parse_args()
    print(make_dataset(RECIPES[args.recipe], args.root))


if __name__ == "__main__":
    main()
