"""Camera-only step lengths smoothed over the whole recording.

Without LiDAR each step's metric length is read from the road plane (`odometry.mono_motion`), about 8 %
off per frame, and the forward filter there can only use readings up to the current frame: the slow
part of its error is what the Sim(3)-aligned trajectory error is made of (on the development clips, the
true step lengths in place of the filtered ones cut the error 2-7x, true rotations changed it by under
5 %). A recorded sequence has the later readings too, so after the window pass the lengths are solved
again over the whole chain: least squares on the log length, with each step's absolute reading and a
vehicle's smooth speed (the step length's change from frame to frame, in metres). A step without a
reading (standing, the filter's fallback) or a restart of the filter breaks the chain."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from leovr.geometry import invert_T


@dataclass(frozen=True)
class LengthReading:
    """One step's absolute length reading as the filter used it: log metres and its sigma (None: the step
    is in the chain but had no reading); `restart` when the filter started over from it (no link to the
    step before)."""

    log_length: float | None
    sigma_log: float = 1.0
    restart: bool = False


def smooth_log_lengths(readings: list[LengthReading | None], change_sigma_m: float = 0.005,
                       iterations: int = 4) -> np.ndarray:
    """Smoothed log step length per step (NaN where the step has no reading). Each run of consecutive
    readings without a restart is one chain: residuals (x_k - r_k) / sigma_k and the change of the step
    length from one frame to the next, (L_k - L_{k-1}) / change_sigma_m in metres (a vehicle's acceleration:
    0.005 m a frame at 10 Hz is 0.5 m/s^2), linearised in the log as (x_k - x_{k-1}) L / change_sigma_m and
    re-solved `iterations` times. In metres, not in the log: stiff at speed, free to brake at a crawl."""
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
        out[k:end] = _solve_chain(readings[k:end], change_sigma_m, iterations)
        k = end
    return out


def _solve_chain(chain: list[LengthReading], change_sigma_m: float, iterations: int) -> np.ndarray:
    m = len(chain)
    read = [r.log_length is not None and np.isfinite(r.log_length) and r.sigma_log > 0 for r in chain]
    w = np.array([1.0 / r.sigma_log if ok else 0.0 for r, ok in zip(chain, read)])
    y = np.array([r.log_length if ok else 0.0 for r, ok in zip(chain, read)])
    if not any(read):  # nothing to solve from: the caller keeps the window pass's lengths
        return np.full(m, np.nan)
    diff = sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m))
    change = np.full(m - 1, 1.0 / 0.1)  # first pass: a loose change of 10 % a frame
    for _ in range(iterations + 1):
        A = sp.vstack([sp.diags(w), sp.diags(change) @ diff]).tocsc()
        x = np.atleast_1d(spsolve((A.T @ A).tocsc(), A.T @ np.r_[w * y, np.zeros(m - 1)]))
        change = np.exp(0.5 * (x[1:] + x[:-1])) / change_sigma_m
    return x


def rescale_steps(poses: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (F x 4 x 4) whose step k (frame k to k + 1) gets the length `lengths[k]`
    (metres; NaN keeps the step as it is), keeping every step's rotation and direction of travel."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        step = invert_T(poses[k - 1]) @ poses[k]
        norm = float(np.linalg.norm(step[:3, 3]))
        if np.isfinite(lengths[k - 1]) and norm > 1e-9:
            step[:3, 3] *= lengths[k - 1] / norm
        out.append(out[-1] @ step)
    return np.stack(out)
