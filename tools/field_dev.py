"""Development runs for the correction field and the pair factors (issue 14, sessions 46-47; development data only).

    collect SPLIT TAG [key=value ...]   refine each Mid-40 drive of the split (env LIDAR, SEEDS) with RefineConfig
                                        overrides; keeps the scored pixels per frame in ROOT/TAG_<drive>.npz
    kitti TAG [key=value ...]           refine the KITTI raw clip's development frames 0-37 (Mid-40-like); keeps the
                                        scored pixels per frame in ROOT/kitti_TAG.npz
    compare TAG [TAG ...]               generator / refined MAE and ATE per drive and summed, per tag
    oracle TAG                          the best correction field of each grid size fitted to the truth
    region TAG                          generator / refined / 8 x 14 oracle MAE inside and outside the Mid-40 cone

ROOT is runs/field_dev (env FIELD_DEV_ROOT). Figures: docs/benchmarks.md, "Pair factors ..." and "Motion stereo's
corners on the correction field" (e.g. `collect val st03 stereo_depth_sigma_log=0.03`, `compare base st03`).
"""

from __future__ import annotations

import glob
import json
import os
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

ROOT = Path(os.environ.get("FIELD_DEV_ROOT", "runs/field_dev"))
H, W = 256, 448  # the simulator's image
GRIDS = [(2, 2), (4, 7), (8, 14), (16, 28)]


def overrides(args: list[str]) -> dict:
    out = {}
    for kv in args:
        k, v = kv.split("=", 1)
        try:
            out[k] = json.loads(v)
        except ValueError:
            out[k] = v
    return out


def save_pixels(col: dict, dst: Path) -> None:
    """A run's scored pixels per frame (`run_refine(..., collect=col)`): rows, cols, truth and every method."""
    d = {}
    for i, fs in col.items():
        d[f"{i}_rows"], d[f"{i}_cols"] = fs.pick
        d[f"{i}_gt"] = fs.gt
        d.update({f"{i}_{k}": v for k, v in fs.pred.items()})
    np.savez_compressed(dst, **d)


def collect(split: str, tag: str, args: list[str]) -> None:
    from leovr.config import RefineConfig
    from leovr.data import open_sequence
    from leovr.depth.dataset import split_entries
    from leovr.pipeline.refine import run_refine
    from leovr.sim.dataset import default_root

    seeds = os.environ.get("SEEDS")
    for e in split_entries(default_root() / "default", split):
        if e["lidar"] != os.environ.get("LIDAR", "mid40") or (seeds and str(e["seed"]) not in seeds.split(",")):
            continue
        name = Path(e["path"]).name
        dst = ROOT / f"{tag}_{name}.npz"
        if dst.exists():
            continue
        col: dict = {}
        run_refine(open_sequence(e["path"]), RefineConfig(**{"input": "full", **overrides(args)}),
                   ROOT / f"work_{tag}_{name}", progress=False, collect=col)
        save_pixels(col, dst)
        print(name, "done", flush=True)


def kitti(tag: str, args: list[str]) -> None:
    from leovr.config import RefineConfig
    from leovr.data import open_sequence
    from leovr.paths import kitti_raw_dir
    from leovr.pipeline.refine import run_refine

    col: dict = {}
    m = run_refine(open_sequence(kitti_raw_dir()), RefineConfig(**{"input": "mid40", "end": 38, **overrides(args)}),
                   ROOT / f"kitti_{tag}", progress=False, collect=col)
    save_pixels(col, ROOT / f"kitti_{tag}.npz")
    print(tag, " ".join(f"{k}={v['mae_m']:.3f}" for k, v in m["depth"].items()))


def compare(tags: list[str]) -> None:
    rows: dict = {}
    for t in tags:
        for w in sorted(glob.glob(str(ROOT / f"work_{t}_*"))):
            m = json.load(open(w + "/metrics.json"))
            d, tr = m["depth"], m["trajectory"]
            rows.setdefault(w.split(f"work_{t}_")[1], {})[t] = (d["generator"]["mae_m"], d["refined"]["mae_m"], tr["leovr"]["ate_m"])
    sums = {t: np.zeros(3) for t in tags}
    for name, r in rows.items():
        print(f"{name:32s}", " | ".join(f"{t}: gen {v[0]:.3f} ref {v[1]:.3f} ate {v[2]:.3f}" for t, v in r.items()))
        for t, v in r.items():
            sums[t] += v
    for t, v in sums.items():
        print(t, "sum gen %.3f ref %.3f ate %.3f" % tuple(v))


def _fit(B: sp.csr_matrix, r: np.ndarray, lam: float = 1e-3) -> np.ndarray:
    """Robust (IRLS, L1-like) least-squares fit of field offsets to log ratios."""
    w = np.ones(len(r))
    for _ in range(8):
        Bw = B.multiply(w[:, None]).tocsr()
        c = spl.spsolve((Bw.T @ B + sp.identity(B.shape[1]) * lam).tocsc(), Bw.T @ r)
        w = 1 / np.maximum(np.abs(B @ c - r), 1e-2)
    return c


def _frames(tag: str):
    from odometry.depth_field import CorrectionGrid

    grids = {g: CorrectionGrid(*g, H, W) for g in GRIDS}
    for f in sorted(glob.glob(str(ROOT / f"{tag}_*.npz"))):
        z = np.load(f)
        for i in sorted({int(k.split("_")[0]) for k in z.files}):
            rows, cols, gt, gen, ref = (z[f"{i}_{k}"] for k in ("rows", "cols", "gt", "generator", "refined"))
            r = np.log(gt) - np.log(np.maximum(gen, 1e-3))
            fitted = {}
            for g, grid in grids.items():
                B = grid.sparse_weights(cols.astype(float), rows.astype(float))
                fitted[g] = np.minimum(gen * np.exp(B @ _fit(B, r)), 255.99)
            fitted["scale"] = np.minimum(gen * np.exp(np.median(r)), 255.99)
            yield Path(f).stem, rows, cols, gt, gen, ref, fitted


def oracle(tag: str) -> None:
    """MAE per drive of the generator, the refined depth and each fitted field; and their mean over the drives."""
    per: dict = {}
    for drive, _, _, gt, gen, ref, fitted in _frames(tag):
        for k, p in [("generator", gen), ("refined", ref)] + [(f"oracle_{g}", v) for g, v in fitted.items()]:
            a = per.setdefault(drive, {}).setdefault(k, [0.0, 0])
            a[0] += np.abs(p - gt).sum()
            a[1] += len(gt)
    mean: dict = {}
    for drive, acc in per.items():
        print(drive, " ".join(f"{k}={v[0] / v[1]:.3f}" for k, v in acc.items()))
        for k, v in acc.items():
            mean[k] = mean.get(k, 0.0) + v[0] / v[1] / len(per)
    print("mean over drives", " ".join(f"{k}={v:.3f}" for k, v in mean.items()))


def region(tag: str) -> None:
    radius = 224 / np.tan(np.radians(40.5)) * np.tan(np.radians(19.2))  # the 38.4-degree cone in the 81-degree image
    acc: dict = {}
    for _, rows, cols, gt, gen, ref, fitted in _frames(tag):
        inside = np.hypot(cols - W / 2, rows - H / 2) < radius
        for reg, m in (("inside", inside), ("outside", ~inside)):
            for k, p in (("generator", gen), ("refined", ref), ("oracle_8x14", fitted[(8, 14)])):
                a = acc.setdefault((reg, k), [0.0, 0])
                a[0] += np.abs(p[m] - gt[m]).sum()
                a[1] += m.sum()
    n = sum(acc[(reg, "generator")][1] for reg in ("inside", "outside"))
    for reg in ("inside", "outside"):
        print(reg, f"pixels {acc[(reg, 'generator')][1] / n:.2f}",
              " ".join(f"{k}={acc[(reg, k)][0] / acc[(reg, k)][1]:.3f}" for k in ("generator", "refined", "oracle_8x14")))


if __name__ == "__main__":
    ROOT.mkdir(parents=True, exist_ok=True)
    cmd, rest = sys.argv[1], sys.argv[2:]
    if cmd == "collect":
        collect(rest[0], rest[1], rest[2:])
    elif cmd == "kitti":
        kitti(rest[0], rest[1:])
    elif cmd == "compare":
        compare(rest)
    elif cmd == "oracle":
        oracle(rest[0])
    elif cmd == "region":
        region(rest[0])
    else:
        sys.exit(__doc__)
