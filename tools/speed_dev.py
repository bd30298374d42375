#!/usr/bin/env python3
"""Development check of refinement speed against accuracy, on development data only (simulator
validation drives, seeds 2000-2002; never the bench speed / bench refine drives). Per drive: refined
MAE, ATE and the per-stage median / p95 ms of one `run_refine` with the given RefineConfig fields.

    .venv/bin/python tools/speed_dev.py NAME [--cfg F=V ...] [--drives D ...]   # appends to runs/speed_dev.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from pose_dev import _value  # field=value parsing, shared with the pose development tool (tools/ is on sys.path)

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.pipeline.refine import run_refine
from leovr.sim.dataset import default_root

DRIVES = [f"{s}_{lidar}_day_{seed}" for s, seed in (("city_loop", "s2000"), ("straight", "s2001"), ("dynamic", "s2002"))
          for lidar in ("mid40", "vlp16")]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("name")
    ap.add_argument("--cfg", nargs="*", default=[], help="RefineConfig field=value")
    ap.add_argument("--drives", nargs="*", default=DRIVES)
    a = ap.parse_args()
    fields = {k: _value(v) for k, v in (s.split("=", 1) for s in a.cfg)}
    cfg = RefineConfig(**fields)
    rows = []
    for d in a.drives:
        with tempfile.TemporaryDirectory() as tmp:
            m = run_refine(open_sequence(default_root() / "default" / "val" / d), cfg, Path(tmp), progress=False)
        st = m["timing"]["stats"]
        row = {"drive": d, "refined_mae": m["depth"]["refined"]["mae_m"], "ate": m["trajectory"]["leovr"]["ate_m"],
               **{f"{k[:-3]}_med": round(v["median"], 1) for k, v in st.items()},
               "graph_p95": round(st["graph_ms"]["p95"], 1)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    print(a.name, " ".join(f"{k} {sum(r[k] for r in rows) / len(rows):.4g}" for k in rows[0] if k != "drive"))
    Path("runs").mkdir(exist_ok=True)
    with open("runs/speed_dev.jsonl", "a") as fh:
        fh.write(json.dumps({"name": a.name, "cfg": fields, "rows": rows}) + "\n")


if __name__ == "__main__":
    main()
