"""Recovery of a window whose update gtsam found (nearly) indeterminate: every landmark anchored by a depth
prior, and the smoother updated again in place or rebuilt from its own factors, so that the run goes on.
Loose landmark priors (camera only) can leave a landmark free along its ray, and a failed iSAM2 update leaves its
Bayes tree without the new variables (the next update fails on them too). When the rebuilt window is still
indeterminate, the landmarks behind (or next to the centre of) a camera that projects them leave it: their
projections' Jacobians blow up there, and no image point can lie behind its camera.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Set as AbstractSet
from typing import Callable

import gtsam
import numpy as np


MIN_LANDMARK_DEPTH_M = 0.1  # a landmark nearer the image plane of a camera that projects it (or behind it) is wrong


def landmark_priors(est: gtsam.Values, centre: np.ndarray, rel: float) -> gtsam.NonlinearFactorGraph:
    """A prior on every landmark of `est`, `rel` per metre of its distance from `centre` (the newest pose)."""
    graph = gtsam.NonlinearFactorGraph()
    for key in est.keys():
        if gtsam.Symbol(key).chr() == ord("l"):
            P = est.atPoint3(key)
            sigma = rel * max(1.0, float(np.linalg.norm(P - centre)))
            graph.add(gtsam.PriorFactorPoint3(key, P, gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
    return graph


def rebuilt(
    old: gtsam.FixedLagSmoother,
    new_smoother: Callable[[], gtsam.FixedLagSmoother],
    incremental: bool,
    centre: np.ndarray,
    rel: float,
    dropped: AbstractSet[int] = frozenset(),
) -> gtsam.FixedLagSmoother:
    """A new smoother (`new_smoother`) from the old one's factors, estimate (iSAM2: linearisation point) and time
    stamps, with a prior on every landmark (`landmark_priors`); the `dropped` keys and their factors left out."""
    est = gtsam.Values(old.getLinearizationPoint() if incremental else old.calculateEstimate())
    for key in dropped:
        if est.exists(key):
            est.erase(key)
    graph = landmark_priors(est, centre, rel)
    factors = old.getFactors()
    for n in range(factors.size()):
        f = factors.at(n)
        if f is not None and not dropped.intersection(f.keys()):
            graph.add(f)
    stamps = gtsam.FixedLagSmootherKeyTimestampMap()
    for key, stamp in old.timestamps().items():
        if key not in dropped:
            stamps.insert((key, stamp))
    smoother = new_smoother()
    smoother.update(graph, est, stamps)
    return smoother


def anchor_landmarks(
    smoother: gtsam.FixedLagSmoother,
    new_smoother: Callable[[], gtsam.FixedLagSmoother],
    incremental: bool,
    centre: np.ndarray,
    index: int,
    failure: Exception,
    rel: float = 1.0,
) -> gtsam.FixedLagSmoother:
    """The smoother to go on with after frame `index`'s update failed: every landmark of the window given a depth
    prior of `rel` per metre at its current estimate, and the window updated again. Batch: in place first (the
    failed update's factors and values are already in the smoother), then, if the system is still indeterminate
    (a landmark left without factors while the window marginalised), rebuilt (`rebuilt`). iSAM2 (Gauss-Newton,
    undamped) is left half-updated by a failed update: its window is always rebuilt. When the rebuilt window is
    still indeterminate, the landmarks behind a camera that projects them (`behind_cameras`) and the landmark gtsam
    names are dropped with their factors, and the window rebuilt again (the graph then retires them). Warns;
    raises RuntimeError when nothing is left to drop (a pose or a depth field without support)."""
    reason = "indeterminate" if "ndetermin" in str(failure) else "could not be updated"
    warnings.warn(
        f"frame {index}: the window's system was {reason}; every landmark got a depth prior of "
        f"{rel} per metre" + (" and the window was rebuilt" if incremental else ""),
        stacklevel=3,
    )
    if not incremental:
        try:
            smoother.update(
                landmark_priors(smoother.calculateEstimate(), centre, rel),
                gtsam.Values(),
                gtsam.FixedLagSmootherKeyTimestampMap(),
            )
            return smoother
        except (RuntimeError, IndexError):
            pass
    dropped: set[int] = set()
    behind: set[int] | None = None  # the old smoother does not change: found once, on the first failure
    while True:
        try:
            return rebuilt(smoother, new_smoother, incremental, centre, rel, dropped)
        except (RuntimeError, IndexError) as exc:
            behind = behind_cameras(smoother, incremental) if behind is None else behind
            named = indeterminate_landmark(exc)
            drop = behind | ({named} if named is not None else set())
            if not drop - dropped:
                raise RuntimeError(  # not a landmark: a pose or a depth field without support
                    f"frame {index}: the window's system stayed indeterminate after every landmark got a "
                    f"depth prior ({str(exc).strip().splitlines()[0]})"
                ) from exc
            names = ", ".join(sorted(gtsam.Symbol(k).string() for k in drop - dropped))
            warnings.warn(f"frame {index}: landmarks {names} left the window", stacklevel=3)
            dropped |= drop


def behind_cameras(smoother: gtsam.FixedLagSmoother, incremental: bool) -> set[int]:
    """The landmarks of the window nearer than MIN_LANDMARK_DEPTH_M to the image plane of a camera that projects
    them, or behind it."""
    est = smoother.getLinearizationPoint() if incremental else smoother.calculateEstimate()
    factors = smoother.getFactors()
    out = set()
    for n in range(factors.size()):
        f = factors.at(n)
        if isinstance(f, gtsam.GenericProjectionFactorCal3_S2):
            x, lm = f.keys()
            if (
                est.exists(x)
                and est.exists(lm)
                and est.atPose3(x).transformTo(est.atPoint3(lm))[2] < MIN_LANDMARK_DEPTH_M
            ):
                out.add(lm)
    return out


def indeterminate_landmark(exc: Exception) -> int | None:
    """The landmark key gtsam's indeterminate-system error names ("... near variable K (Symbol: l12)"), or None."""
    m = re.search(r"Symbol: l(\d+)\)", str(exc))
    return gtsam.symbol("l", int(m.group(1))) if m else None
