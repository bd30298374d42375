"""Development check of the photometric masks on traffic validation sequences (never the test split):
precision / recall of each test against the simulator's moving masks, for mask settings; with
--checkpoint, the refinement stage's masks (graph and auto-mask over that generator).

    .venv/bin/python tools/mask_dev.py SEQ [SEQ ...] [--set rigid_abs_px=0.5 rigid_rel=0.3 ...] [--checkpoint G.pt]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from leovr.config import SelfSupConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator
from selfsup.mask_quality import score_masks


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    ap.add_argument("--set", nargs="*", default=[], help="SelfSupConfig field=value")
    ap.add_argument("--work", default="runs/mask_dev")
    ap.add_argument("--focal", type=float, default=130.0)
    ap.add_argument("--checkpoint", type=Path, default=None, help="refinement-stage masks: the graph over this generator")
    a = ap.parse_args()
    kw = {k: yaml.safe_load(v) for k, v in (s.split("=", 1) for s in a.set)}
    cfg = SelfSupConfig(train_focal_px=a.focal, **kw)
    for path in a.sequences:
        work = Path(a.work) / (Path(path).name + ("" if a.checkpoint is None else "_" + a.checkpoint.parent.name))
        model = None if a.checkpoint is None else load_generator(a.checkpoint)
        r = score_masks(open_sequence(path), cfg, work, model, checkpoint=a.checkpoint)
        print(json.dumps({"sequence": Path(path).name, "set": kw, "moving_share": round(r["moving_share"], 4),
                          "moving_with_depth": round(r["moving_with_depth"], 3),
                          **{v: {k: round(x, 3) for k, x in m.items()} for v, m in r["variants"].items()}}), flush=True)


if __name__ == "__main__":
    main()
