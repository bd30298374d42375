"""Where the refined depth's error lies, and two post hoc variants near the returns (issue 14, session 50;
development data only: `tools/field_dev.py collect val TAG` and `tools/field_dev.py kitti TAG` runs).

    FIELD_DEV_ROOT=ROOT tools/refined_error_dev.py where TAG          simulator: the error split by range bin and
                                                                      Mid-40 cone, by depth edge / mover, and the
                                                                      > 80 m pixels inside the cone
    FIELD_DEV_ROOT=ROOT tools/refined_error_dev.py near TAG val|kitti the generator's depth near the frame's returns
                                                                      (log blend, weight exp(-distance / S px)) and
                                                                      the returns re-imposed on the refined depth
                                                                      (normalised convolution of log residuals, sigma
                                                                      G px, faded by exp(-distance / F px), residuals
                                                                      beyond CLIP dropped); env CLIP (default: none);
                                                                      and refined / generator within 20 px of a return

Scored on the run's own pixels; simulator figures are means over the drives. Figures: docs/benchmarks.md,
"Photometric correction outside the cone", session 50 paragraph.
"""

from __future__ import annotations

import glob
import os
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.paths import kitti_raw_dir
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.sim.dataset import default_root

ROOT = Path(os.environ.get("FIELD_DEV_ROOT", "runs/field_dev"))
H, W = 256, 448
RADIUS = 224 / np.tan(np.radians(40.5)) * np.tan(np.radians(19.2))  # the 38.4-degree cone in the 81-degree image


def runs(tag: str, which: str):
    """(drive name, its sequence, its work folder, its scored pixels) of a collect or kitti run."""
    if which == "kitti":
        yield "kitti", open_sequence(kitti_raw_dir()), ROOT / f"kitti_{tag}", np.load(ROOT / f"kitti_{tag}.npz")
        return
    for f in sorted(glob.glob(str(ROOT / f"{tag}_*.npz"))):
        name = Path(f).stem[len(tag) + 1:]
        yield name, open_sequence(default_root() / "default" / "val" / name), ROOT / f"work_{tag}_{name}", np.load(f)


def frames(z):
    for i in sorted({int(k.split("_")[0]) for k in z.files}):
        yield i, *(z[f"{i}_{k}"] for k in ("rows", "cols", "gt", "generator", "refined"))


def where(tag: str) -> None:
    acc: dict = {}
    far: list = []
    for _, seq, _, z in runs(tag, "val"):
        for i, rows, cols, gt, gen, ref in frames(z):
            fr = seq[i]
            ld = np.log(np.where(fr.depth > 0, fr.depth, 1e3))
            spread = (maximum_filter(ld, 7) - minimum_filter(ld, 7))[rows, cols]  # log depth range in 7 x 7
            moving = fr.moving_mask[rows, cols].astype(bool) if fr.moving_mask is not None else np.zeros(len(gt), bool)
            inside = np.hypot(cols - W / 2, rows - H / 2) < RADIUS
            edge = spread > 0.15
            b = np.digitize(gt, [20, 40, 60, 80])
            parts = {("all",): np.ones(len(gt), bool), ("cone", "in"): inside, ("cone", "out"): ~inside,
                     ("kind", "edge"): edge & ~moving, ("kind", "moving"): moving, ("kind", "smooth static"): ~edge & ~moving}
            parts.update({("bin", k, reg): (b == k) & m for k in range(5) for reg, m in (("in", inside), ("out", ~inside))})
            for key, m in parts.items():
                a = acc.setdefault(key, np.zeros(3))
                a += [np.abs(gen[m] - gt[m]).sum(), np.abs(ref[m] - gt[m]).sum(), m.sum()]
            m = inside & (gt > 80)
            far.append(np.column_stack([np.abs(ref[m] - gt[m]), spread[m]]))
    total = acc[("all",)]
    print(f"{'part':26s} pixels  generator  refined  share of the refined error")
    for key, a in acc.items():
        print(f"{' '.join(map(str, key)):26s} {a[2] / total[2]:6.3f} {a[0] / a[2]:9.3f} {a[1] / a[2]:8.3f} {a[1] / total[1]:8.3f}")
    e, spread = np.concatenate(far).T
    for lo, hi in ((0, 0.15), (0.15, 0.5), (0.5, np.inf)):
        m = (spread >= lo) & (spread < hi)
        print(f"> 80 m inside the cone, log depth range {lo}-{hi} in 7 x 7: {m.mean():.3f} of the pixels, "
              f"refined {e[m].mean():.2f} m, {e[m].sum() / e.sum():.3f} of their error")


def near(tag: str, which: str) -> None:
    clip = float(os.environ.get("CLIP", np.inf))
    ccfg = completion_config(RefineConfig(input="mid40" if which == "kitti" else "full"))
    per: dict = {}
    for name, seq, work, z in runs(tag, which):
        acc: dict = {}
        for i, rows, cols, gt, gen, ref in frames(z):
            sparse = frame_sample(seq, i, ccfg, None, 0.1, False, truth=False).sparse
            depth = read_depth_png(work / "depth" / f"{i:06d}.png")  # the refined depth as written
            dist = cv2.distanceTransform((sparse <= 0).astype(np.uint8), cv2.DIST_L2, 5)
            variants = {"refined": ref, "generator": gen}
            for s in (4, 8, 16, 32):  # the generator near returns
                w = np.exp(-dist[rows, cols] / s)
                variants[f"generator near returns, S {s}"] = np.exp(np.log(ref) + w * (np.log(gen) - np.log(ref)))
            m = (sparse > 0) & (depth > 0)
            r = np.zeros(sparse.shape, np.float32)
            r[m] = np.log(sparse[m]) - np.log(depth[m])
            m &= np.abs(r) < clip
            r[~m] = 0
            dist_m = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5)
            for g in (4, 16):  # the returns re-imposed
                k = int(3 * g) | 1
                num, den = cv2.GaussianBlur(r, (k, k), g), cv2.GaussianBlur(m.astype(np.float32), (k, k), g)
                corr = np.where(den > 1e-6, num / np.maximum(den, 1e-6), 0)
                for f in (8, 32):
                    out = depth * np.exp(np.exp(-dist_m / f) * corr)
                    variants[f"returns re-imposed, G {g} F {f}"] = out[rows, cols]
            for k, p in variants.items():
                a = acc.setdefault(k, np.zeros(2))
                a += [np.abs(p - gt).sum(), len(gt)]
            close = dist[rows, cols] < 20
            for part, c in (("within 20 px of a return", close), ("beyond 20 px", ~close)):
                for k, p in (("refined", ref), ("generator", gen)):
                    a = acc.setdefault(f"{k}, {part}", np.zeros(2))
                    a += [np.abs(p[c] - gt[c]).sum(), c.sum()]
        per[name] = {k: v[0] / v[1] for k, v in acc.items()}
        print(name, "done", flush=True)
    for k in next(iter(per.values())):
        print(f"{k:34s} mean {np.mean([p[k] for p in per.values()]):.4f}  ", " ".join(f"{p[k]:.3f}" for p in per.values()))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "where":
        where(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "near" and sys.argv[3] in ("val", "kitti"):
        near(sys.argv[2], sys.argv[3])
    else:
        sys.exit(__doc__)
