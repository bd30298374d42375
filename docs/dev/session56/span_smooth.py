"""Session 56 (issue 16), development data only: the whole-recording step-length smoother with road readings
over spans of j frames (k-j -> k) besides the one-step readings, scored as Sim(3) ATE of leovr's camera-only
motion alone with the smoothed lengths (the `smooth_0.005` column of tools/step_length_dev.py is the shipped
smoother on the same motion).

    .venv/bin/python docs/dev/session56/span_smooth.py [--variants ...] -- SEQ ...
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "tools"))
from multi_road import cached_motion, span_reading  # noqa: E402
from step_length_dev import chain, dev_runs  # noqa: E402

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from leovr.pipeline.refine import road_height  # noqa: E402
from odometry.mono_vo import gray  # noqa: E402
from odometry.step_length import rescale_steps, smooth_log_lengths  # noqa: E402


def smooth_spans(readings, spans, dirs, change_sigma_m=0.005, iterations=6, singles=True):
    """readings: per step (as shipped); spans: list of (first_step, last_step_exclusive, log_chord, sigma);
    dirs: per step unit world direction (m x 3)."""
    base = smooth_log_lengths(readings, change_sigma_m) if singles else np.full(len(readings), np.nan)
    n = len(readings)
    out = np.full(n, np.nan)
    k = 0
    while k < n:
        if readings[k] is None:
            k += 1
            continue
        end = k + 1
        while end < n and readings[end] is not None and not readings[end].restart:
            end += 1
        sub = [(a - k, b - k, y, s) for a, b, y, s in spans if a >= k and b <= end]
        out[k:end] = _chain(readings[k:end], sub, dirs[k:end], base[k:end], change_sigma_m, iterations, singles)
        k = end
    return out


def _chain(chain_r, sub, u, x0, change_sigma_m, iterations, singles):
    m = len(chain_r)
    ok = [singles and r.log_length is not None and np.isfinite(r.log_length) for r in chain_r]
    w = np.array([1.0 / r.sigma_log if o else 0.0 for r, o in zip(chain_r, ok)])
    y = np.array([r.log_length if o else 0.0 for r, o in zip(chain_r, ok)])
    if not any(ok) and not sub:
        return np.full(m, np.nan)
    x = x0.copy()
    if not np.isfinite(x).all():
        guess = np.median([yy - np.log(b - a) for a, b, yy, _ in sub]) if sub else np.nanmedian(y[w > 0])
        x = np.where(np.isfinite(x), x, guess)
    diff = sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m))
    for _ in range(iterations):
        L = np.exp(x)
        change = np.exp(0.5 * (x[1:] + x[:-1])) / change_sigma_m
        rows, rhs = [sp.diags(w), sp.diags(change) @ diff], [w * y, np.zeros(m - 1)]
        if sub:
            J = sp.lil_matrix((len(sub), m))
            b = np.zeros(len(sub))
            for r_i, (a, e, yy, s) in enumerate(sub):
                S = (L[a:e, None] * u[a:e]).sum(0)
                c2 = float(S @ S)
                jac = L[a:e] * (u[a:e] @ S) / c2
                J[r_i, a:e] = jac / s
                b[r_i] = (yy - 0.5 * np.log(c2) + jac @ x[a:e]) / s
            rows.append(J.tocsr())
            rhs.append(b)
        A = sp.vstack(rows).tocsc()
        x = np.atleast_1d(spsolve((A.T @ A).tocsc(), A.T @ np.concatenate(rhs)))
    return x


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    a = ap.parse_args()
    CACHE = Path("runs/s56")
    for path, seq, ref, ref_name, cfg, gen in dev_runs(a.sequences):
        steps, readings = cached_motion(path, seq, cfg, gen)
        P = chain(steps)
        n = len(P)
        K = seq[0].K
        cam_h = road_height(seq, cfg) or 1.65
        cf = CACHE / f"spans_{Path(path).name}.pkl"
        if cf.exists():
            span_r = pickle.loads(cf.read_bytes())
        else:
            grays = [gray(seq[i].image) for i in range(n)]
            span_r = {}
            for j in (1, 2, 3, 4, 6):
                for k in range(j, n):
                    T = invert_T(P[k - j]) @ P[k]
                    L = np.linalg.norm(T[:3, 3])
                    if L < 1e-6:
                        continue
                    T[:3, 3] /= L
                    r = span_reading(grays, k, j, T, K, cam_h)
                    if r is not None:
                        span_r[(k, j)] = r
            cf.write_bytes(pickle.dumps(span_r))
        dirs = np.stack([P[s][:3, :3] @ (steps[s][:3, 3] / max(np.linalg.norm(steps[s][:3, 3]), 1e-9))
                         for s in range(n - 1)])
        # a step of the filter with no length (standing) has a zero translation; keep any unit vector
        sig0 = 0.08

        base = smooth_log_lengths(readings, 0.005)
        Lb = np.exp(np.nan_to_num(base, nan=-20.0))

        def gated(spans, g=3.0):
            keep = []
            for a_, b_, y_, s_ in spans:
                pred = np.log(max(np.linalg.norm((Lb[a_:b_, None] * dirs[a_:b_]).sum(0)), 1e-9))
                if abs(y_ - pred) <= g * np.hypot(s_, 0.05):
                    keep.append((a_, b_, y_, s_))
            return keep

        def spans_of(js, min_chord=None, only_long=False):
            out = []
            for (k, j), (y, inl) in span_r.items():
                if j not in js:
                    continue
                if min_chord is not None:  # the shortest span whose (filtered) chord reaches min_chord
                    ch = lambda jj: np.linalg.norm((invert_T(P[k - jj]) @ P[k])[:3, 3])
                    if ch(j) < min_chord and j != max(js):
                        continue
                    if any(ch(jj) >= min_chord for jj in js if jj < j):
                        continue
                    if only_long and j == 1:
                        continue
                out.append((k - j, k, y, sig0 * np.sqrt(max(1.0, 20.0 / inl))))
            return out

        row = {"sequence": Path(path).name}
        ate = lambda x: round(trajectory_metrics(rescale_steps(P, np.exp(x)), ref, "sim3")["ate_m"], 4)
        row["shipped"] = ate(smooth_log_lengths(readings, 0.005))
        for mc in (0.3, 0.5, 1.0):
            sp_ = spans_of((1, 2, 3, 4, 6), mc, only_long=True)
            row[f"add{mc}"] = ate(smooth_spans(readings, sp_, dirs))
            row[f"add{mc}_gated"] = ate(smooth_spans(readings, gated(sp_), dirs))
            row[f"n_add{mc}"] = f"{len(gated(sp_))}/{len(sp_)}"
        for name, js, singles, mc in (("j2", (2,), True, None), ("j3", (3,), True, None), ("j2+3", (2, 3), True, None),
                                      ("only3", (3,), False, None), ("only1-3", (1, 2, 3), False, None),
                                      ("j4", (4,), True, None), ("j6", (6,), True, None),
                                      ("adapt0.5", (1, 2, 3, 4, 6), False, 0.5), ("adapt1", (1, 2, 3, 4, 6), False, 1.0),
                                      ("adapt2", (1, 2, 3, 4, 6), False, 2.0)):
            row[name] = ate(smooth_spans(readings, spans_of(js, mc), dirs, singles=singles))
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
