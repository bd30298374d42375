"""The time rules of a ROS bag's messages (leovr.data.rosbag): the unit of a cloud's per-point times, an image's
sweep by the sweeps' time spans, and the messages of a topic whose stamps can be trusted."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from leovr.errors import DataError


def point_time_scale(
    path: Path, topic: str, spans: list[tuple[float, float, bool] | None], period_s: float
) -> float | None:
    """The factor that brings the clouds' per-point time offsets to seconds: 1 when a sweep's times span
    between 5 % and twice the scan period, else the power of 1000 that makes them (a driver writing ms or
    us; said in a warning); None when none does (the times are not used, said too)."""
    spread = [b - a for sp in spans if sp is not None and not sp[2] for a, b in [sp[:2]]]
    if not spread or period_s <= 0 or np.median(spread) <= 0:
        return 1.0
    ratio = float(np.median(spread)) / period_s
    for scale in (1.0, 1e-3, 1e3, 1e-6, 1e6):
        if 0.05 <= ratio * scale <= 2.0:
            if scale != 1.0:
                warnings.warn(
                    f"{path}: {topic}: a sweep's per-point times span {np.median(spread):.6g} s as read, "
                    f"{ratio:.3g}x the scan period of {period_s:.3f} s: read x{scale:g} (another unit)",
                    stacklevel=4,
                )
            return scale
    warnings.warn(
        f"{path}: {topic}: a sweep's per-point times span {np.median(spread):.6g} s, {ratio:.3g}x the scan "
        f"period of {period_s:.3f} s, in no unit a sweep's could: not used",
        stacklevel=4,
    )
    return None


def pair_by_span(t: np.ndarray, lo: np.ndarray, hi: np.ndarray, stamp: np.ndarray, max_gap: np.ndarray) -> np.ndarray:
    """Index of the span [lo, hi] that holds each time of `t` (of those that do, the one whose middle is
    nearest; on a tie, whose `stamp` is), else of the nearest span within its `max_gap`; -1 when none is.
    Times in integer ns, taken relative to the first span's start (float64 then resolves them to the ns)."""
    if not len(lo):
        return np.full(len(t), -1, np.int64)
    t0 = int(lo.min())
    t, lo, hi, stamp = t - t0, lo - t0, hi - t0, stamp - t0
    order = np.argsort(lo, kind="stable")
    lo_s, hi_s, st_s, gap_s = lo[order], hi[order], stamp[order], np.asarray(max_gap, np.float64)[order]
    j = np.searchsorted(lo_s, t, side="right") - 1
    cand = np.clip(j[:, None] + np.arange(-2, 2)[None], 0, len(lo) - 1)
    tt = t[:, None].astype(np.float64)
    gap = np.maximum(lo_s[cand] - tt, 0.0) + np.maximum(tt - hi_s[cand], 0.0)
    closeness = np.abs((lo_s[cand] + hi_s[cand]) / 2.0 - tt) + 1e-3 * np.abs(st_s[cand] - tt)
    best = np.argmin(np.where(gap == gap.min(1, keepdims=True), closeness, np.inf), axis=1)
    rows = np.arange(len(t))
    return np.where(gap[rows, best] <= gap_s[cand[rows, best]], order[cand[rows, best]], -1).astype(np.int64)


CLOCK_GAP_S = 3600.0  # stamps this far from the rest of their topic come from another clock (or none: stamp 0)


def increasing(path: Path, topic: str, stamps: list[int]) -> list[int]:
    """Indices of the messages kept, in recording order: the largest set whose stamps increase in that order
    (one stamp glitch, back or ahead, loses that message only), within the largest stretch of them without a
    gap of an hour (a clock not set stamps 0). The others are named in one warning; a topic that would lose
    more than half its messages is refused."""
    kept = _longest_increasing(stamps)
    t = np.array([stamps[k] for k in kept], np.float64) * 1e-9
    cuts = np.nonzero(np.diff(t) > CLOCK_GAP_S)[0] + 1
    parts = np.split(np.arange(len(kept)), cuts)
    best = max(parts, key=len)
    kept = [kept[j] for j in best]
    kept_set = set(kept)
    dropped = [k for k in range(len(stamps)) if k not in kept_set]
    if len(dropped) * 2 > len(stamps):
        raise DataError(
            path,
            f"{topic}: the stamps of {len(dropped)} of {len(stamps)} messages repeat, go back or "
            f"jump against the recording order ({_glitch(stamps, dropped[0])}): not a recording "
            "leovr can order",
        )
    if dropped:
        warnings.warn(
            f"{path}: {topic}: {len(dropped)} message(s) whose stamp repeats, goes back or jumps against "
            f"the recording order left out ({'; '.join(_glitch(stamps, k) for k in dropped[:5])}"
            f"{'; ...' if len(dropped) > 5 else ''})",
            stacklevel=4,
        )
    return kept


def _glitch(stamps: list[int], k: int) -> str:
    """How message k's stamp stands against the messages recorded beside it."""
    s = stamps[k]
    if k and s == stamps[k - 1]:
        return f"message {k} stamped {s * 1e-9:.6f} s repeats message {k - 1}'s {stamps[k - 1] * 1e-9:.6f} s"
    if k and s < stamps[k - 1]:
        return f"message {k} stamped {s * 1e-9:.6f} s goes back from message {k - 1}'s {stamps[k - 1] * 1e-9:.6f} s"
    if k + 1 < len(stamps):
        return f"message {k} stamped {s * 1e-9:.6f} s, message {k + 1} {stamps[k + 1] * 1e-9:.6f} s"
    return f"message {k} stamped {s * 1e-9:.6f} s"


def _longest_increasing(stamps: list[int]) -> list[int]:
    """Indices of a longest strictly increasing subsequence of `stamps` (patience sorting), the first of
    repeated stamps kept."""
    import bisect

    tails: list[int] = []  # stamps ending the best subsequence of each length
    ends: list[int] = []  # ... and their indices
    parent = [-1] * len(stamps)
    for k, s in enumerate(stamps):
        j = bisect.bisect_left(tails, s)
        if j < len(tails) and tails[j] == s:  # a repeat: the earlier message stays
            continue
        parent[k] = ends[j - 1] if j else -1
        if j == len(tails):
            tails.append(s)
            ends.append(k)
        else:
            tails[j], ends[j] = s, k
    out, k = [], ends[-1] if ends else -1
    while k >= 0:
        out.append(k)
        k = parent[k]
    return out[::-1]
