"""The photometric correction (odometry.photo_field) applied after the fact to `tools/field_dev.py collect` runs
(issue 14, session 48; development drives only): each scored frame's refined depth PNG, the run's poses
(poses_kitti.txt) and the drive's images; scores the corrected depth on the run's scored pixels, inside and
outside the Mid-40 cone (mean over drives of the per-drive MAE), and the distribution of the poses' check (bias).

    FIELD_DEV_ROOT=ROOT tools/photo_field_dev.py TAG
env: OFFS (neighbour offsets, negative = after; default 1,2,3,-1,-2,-3), GRID (rows,cols; 16,28), GAIN (0.05),
DS (downsample; 0: by sweep_pixels), PP (patch half size, 2), FAR / FARGAIN (the far candidate; 0: off), CHECK (the
poses' check, max_bias_log), FREE (returns: nodes without a return of the frame's own scan, the shipped rule; cone: nodes
outside the cone's circle), SPAN / NC (candidates' span and count), TEX (min_texture), SHARE (min_backed_share), KITTI=1 (TAG is a `field_dev.py kitti` run), FADE (px: the correction times 1 - exp(-distance to the frame's nearest return / FADE);
0: off). Defaults: the shipped settings."""
from __future__ import annotations

import glob
import os
import sys
import time
from pathlib import Path
import cv2
import numpy as np

from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.sim.dataset import default_root
from odometry.photo_field import PhotoFieldSettings, photometric_offsets, photometric_correction, free_nodes
from leovr.pipeline.refine import completion_config, frame_sample
from leovr.config import RefineConfig

ROOT = Path(os.environ.get('FIELD_DEV_ROOT', 'runs/field_dev'))
tag = sys.argv[1]
offs = [int(x) for x in os.environ.get('OFFS', '1,2,3,-1,-2,-3').split(',')]
gr = [int(x) for x in os.environ.get('GRID', '16,28').split(',')]
d = PhotoFieldSettings()  # the shipped settings, each overridable
s = PhotoFieldSettings(rows=gr[0], cols=gr[1], min_gain=float(os.environ.get("GAIN", d.min_gain)), downsample=int(os.environ.get("DS", d.downsample)), patch_px=int(os.environ.get("PP", d.patch_px)), far_log=float(os.environ.get("FAR", d.far_log)), far_gain=float(os.environ.get("FARGAIN", d.far_gain)), max_bias_log=float(os.environ.get("CHECK", d.max_bias_log)), span_log=float(os.environ.get("SPAN", d.span_log)), candidates=int(os.environ.get("NC", d.candidates)), min_texture=float(os.environ.get("TEX", d.min_texture)), min_backed_share=float(os.environ.get("SHARE", d.min_backed_share)))
H, W = 256, 448
FADE = float(os.environ.get('FADE', 0))
radius = 224 / np.tan(np.radians(40.5)) * np.tan(np.radians(19.2))
acc = {}; tsum = [0.0, 0]; per_frame = []
KITTI = os.environ.get('KITTI', '') == '1'
if KITTI:  # a `field_dev.py kitti TAG` run: the KITTI clip's development frames, Mid-40-like input
    from leovr.paths import kitti_raw_dir
    H, W = 375, 1242
    radius = 721.5 * np.tan(np.radians(19.2))  # the cone's circle at KITTI's focal length
ccfg = completion_config(RefineConfig(input='mid40' if KITTI else 'full'))  # the frames' own returns
runs = [str(ROOT / f'kitti_{tag}')] if KITTI else sorted(glob.glob(str(ROOT / f'work_{tag}_*')))
for w in runs:
    name = 'kitti' if KITTI else w.split(f'work_{tag}_')[1]
    seq = open_sequence(kitti_raw_dir()) if KITTI else open_sequence(default_root() / 'default' / 'val' / name)
    z = np.load(ROOT / f'kitti_{tag}.npz') if KITTI else np.load(ROOT / f'{tag}_{name}.npz')
    est = np.loadtxt(w + '/poses_kitti.txt').reshape(-1, 3, 4)
    est = np.concatenate([est, np.tile([[[0, 0, 0, 1.]]], (len(est), 1, 1))], 1)
    frames = sorted({int(k.split('_')[0]) for k in z.files})
    gray = lambda j: cv2.cvtColor(seq[j].image, cv2.COLOR_RGB2GRAY)
    for i in frames:
        js = [i - o for o in offs if 0 <= i - o < len(est)]
        if not js: continue
        D = read_depth_png(Path(w) / 'depth' / f'{i:06d}.png')
        if os.environ.get('FREE', 'returns') == 'returns':
            smp = frame_sample(seq, i, ccfg, None, 0.1, False, truth=False)
            free = free_nodes(smp.sparse, s)
        else:
            nr, nc = np.divmod(np.arange(s.rows * s.cols), s.cols)
            free = np.hypot(nc * (W - 1) / (s.cols - 1) - W / 2, nr * (H - 1) / (s.rows - 1) - H / 2) > radius
        nb = [(gray(j), np.linalg.inv(est[j]) @ est[i]) for j in js]
        t0 = time.perf_counter()
        st: dict = {}
        off = photometric_offsets(D, gray(i), nb, seq[i].K, free, s, st)
        C = photometric_correction(D, off, s)
        if FADE > 0:  # the correction faded near the frame's own returns: exp(-distance / FADE px)
            if os.environ.get('FREE', 'returns') != 'returns':
                smp = frame_sample(seq, i, ccfg, None, 0.1, False, truth=False)
            dist = cv2.distanceTransform((smp.sparse <= 0).astype(np.uint8), cv2.DIST_L2, 5)
            fade = 1.0 - np.exp(-dist / FADE)
            C = np.where(D > 0, D * np.exp(fade * np.log(np.maximum(C, 1e-6) / np.maximum(D, 1e-6))), 0.0)
        tsum[0] += time.perf_counter() - t0; tsum[1] += 1
        rows, cols, gt, ref, gen = (z[f'{i}_{k}'] for k in ('rows', 'cols', 'gt', 'refined', 'generator'))
        corr = np.minimum(C[rows, cols], 255.99)
        inside = np.hypot(cols - W / 2, rows - H / 2) < radius
        for reg, m in (('in', inside), ('out', ~inside), ('all', np.ones_like(inside))):
            for k, p in (('ref', ref), ('photo', corr), ('gen', gen)):
                a = acc.setdefault((name, reg, k), [0.0, 0]); a[0] += np.abs(p[m] - gt[m]).sum(); a[1] += m.sum()
        per_frame.append((name, i, st.get('bias', np.inf), st.get('backed', 0), st.get('eligible', 0),
                          np.abs(corr - gt).mean() - np.abs(ref - gt).mean()))
    print(name, ' '.join(f'{k}={v[0]/max(v[1],1):.3f}' for (n, r, k), v in acc.items() if n == name and r == 'all'), flush=True)
tot = {}
for (n, r, k), v in acc.items():
    tot.setdefault((r, k), []).append(v[0] / max(v[1], 1))
for (r, k), v in sorted(tot.items()):
    print('mean', r, k, f'{np.mean(v):.3f}')
print(f'ms per frame {1000 * tsum[0] / tsum[1]:.0f}')
pf = np.array([(b_, n_, e_) for _, _, b_, n_, e_, _ in per_frame])
passing = (np.abs(pf[:, 0]) <= s.max_bias_log) & (pf[:, 1] >= np.maximum(s.min_backed, s.min_backed_share * pf[:, 2]))
b = pf[:, 0]
print('check: frames passing', f'{np.mean(passing):.2f}', 'bias 5/25/50/75/95 %', np.round(np.percentile(b[np.isfinite(b)], [5, 25, 50, 75, 95]), 3),
      'share of the nodes with returns that chose clearly, 5/50/95 %', np.round(np.percentile(pf[:, 1] / np.maximum(pf[:, 2], 1), [5, 50, 95]), 2))
dm = np.array([d_ for *_, d_ in per_frame])  # what the sweep did to each frame's MAE
print('frames made better', f'{np.mean(dm < 0):.2f}', 'mean change per frame by |bias|:',
      ' '.join(f'{lo}-{hi}: {dm[k].mean():+.3f} ({k.sum()})' for lo, hi in ((0, 0.03), (0.03, 0.05), (0.05, 0.08), (0.08, 0.12), (0.12, 0.2), (0.2, np.inf))
               for k in [(np.abs(pf[:, 0]) >= lo) & (np.abs(pf[:, 0]) < hi)] if k.any()))
if os.environ.get('FRAMES'):  # per frame: the check's figures and what the sweep did to the frame's MAE
    np.save(os.environ['FRAMES'], np.array([(b_, n_, e_, d_) for _, _, b_, n_, e_, d_ in per_frame]))
