#!/usr/bin/env python3
"""Frame-to-frame motion errors of a refine run against ground truth: leovr's poses and the KISS-ICP
poses recorded beside them (progress.json), per frame and as medians, with each frame's initial-pose
source. Shows whether leovr's error is per frame or accumulated (drift).

    .venv/bin/leovr refine SEQ --input full --out RUN
    .venv/bin/python tools/relative_errors.py RUN SEQ
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from leovr.data import open_sequence
from leovr.geometry import invert_T


def motion_errors(est: list[np.ndarray], gt: list[np.ndarray]) -> np.ndarray:
    """Per consecutive pair: rotation error (degrees) and translation error (m) of the relative motion."""
    out = []
    for i in range(1, len(est)):
        d = invert_T(invert_T(gt[i - 1]) @ gt[i]) @ (invert_T(est[i - 1]) @ est[i])
        out.append((np.degrees(Rotation.from_matrix(d[:3, :3]).magnitude()), np.linalg.norm(d[:3, 3])))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run", type=Path)
    ap.add_argument("sequence")
    a = ap.parse_args()
    seq = open_sequence(a.sequence)
    progress = json.loads((a.run / "progress.json").read_text())
    keys = sorted(progress["poses"], key=int)
    gt = [seq[int(k)].T_world_cam for k in keys]
    err = {name: motion_errors([np.array(progress[field][k]).reshape(4, 4) for k in keys], gt)
           for name, field in (("leovr", "poses"), ("kiss_icp", "icp_poses")) if len(progress.get(field, {})) == len(keys)}
    for n, k in enumerate(keys[1:]):
        print(k, progress["sources"][k], "  ".join(f"{name} {e[n, 0]:.3f} deg {e[n, 1]:.3f} m" for name, e in err.items()))
    sources = list(progress["sources"].values())
    print(json.dumps({"median": {name: {"rotation_deg": round(float(np.median(e[:, 0])), 3),
                                        "translation_m": round(float(np.median(e[:, 1])), 3)} for name, e in err.items()},
                      "sources": {s: sources.count(s) for s in sorted(set(sources))}}))


if __name__ == "__main__":
    main()
