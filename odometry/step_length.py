"""Camera-only step lengths smoothed over the whole recording.

Without LiDAR each step's metric length is read from the road plane (`odometry.mono_motion`), about 8 %
off per frame, and the forward filter there can only use readings up to the current frame: the slow
part of its error is what the Sim(3)-aligned trajectory error is made of (on the development clips, the
true step lengths in place of the filtered ones cut the error 2-3x, true rotations changed it by under
5 %). A recorded sequence has the later readings too, so after the window pass the lengths are solved
again over the whole chain: least squares on the log length, with each step's absolute reading and a
vehicle's smooth speed (small second differences, loosely small first differences). A step without a
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


def smooth_log_lengths(readings: list[LengthReading | None], accel_sigma_log: float = 0.001,
                       speed_sigma_log: float = 0.02) -> np.ndarray:
    """Smoothed log step length per step (NaN where the step has no reading). Each run of consecutive
    readings without a restart is one chain: residuals (x_k - r_k) / sigma_k, (x_k - x_{k-1}) /
    speed_sigma_log and (x_k - 2 x_{k-1} + x_{k-2}) / accel_sigma_log, solved as sparse normal equations."""
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
        out[k:end] = _solve_chain(readings[k:end], accel_sigma_log, speed_sigma_log)
        k = end
    return out


def _solve_chain(chain: list[LengthReading], accel: float, speed: float) -> np.ndarray:
    m = len(chain)
    w = np.array([0.0 if r.log_length is None else 1.0 / r.sigma_log for r in chain])
    rows = [sp.diags(w)]
    rhs = [w * np.array([0.0 if r.log_length is None else r.log_length for r in chain])]
    if m > 1:
        rows.append(sp.diags([-np.ones(m - 1), np.ones(m - 1)], [0, 1], shape=(m - 1, m)) / speed)
        rhs.append(np.zeros(m - 1))
    if m > 2:
        rows.append(sp.diags([np.ones(m - 2), -2 * np.ones(m - 2), np.ones(m - 2)], [0, 1, 2], shape=(m - 2, m)) / accel)
        rhs.append(np.zeros(m - 2))
    A = sp.vstack(rows).tocsc()
    return np.atleast_1d(spsolve((A.T @ A).tocsc(), A.T @ np.concatenate(rhs)))


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
