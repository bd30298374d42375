"""Recovery of a window whose update gtsam found (nearly) indeterminate: every landmark anchored by a depth
prior, and the smoother updated again in place or rebuilt from its own factors, so that the run goes on.
Loose landmark priors (camera only) can leave a landmark free along its ray, and a failed iSAM2 update leaves its
Bayes tree without the new variables (the next update fails on them too).
"""

from __future__ import annotations

import warnings
from typing import Callable

import gtsam
import numpy as np


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
) -> gtsam.FixedLagSmoother:
    """A new smoother (`new_smoother`) from the old one's factors, estimate (iSAM2: linearisation point) and time
    stamps, with a prior on every landmark (`landmark_priors`)."""
    est = old.getLinearizationPoint() if incremental else old.calculateEstimate()
    graph = landmark_priors(est, centre, rel)
    factors = old.getFactors()
    for n in range(factors.size()):
        if factors.at(n) is not None:
            graph.add(factors.at(n))
    stamps = gtsam.FixedLagSmootherKeyTimestampMap()
    for key, stamp in old.timestamps().items():
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
    undamped) is left half-updated by a failed update: its window is always rebuilt. Warns; raises RuntimeError
    when the rebuilt window is indeterminate too (a pose or a depth field without support)."""
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
    try:
        return rebuilt(smoother, new_smoother, incremental, centre, rel)
    except (RuntimeError, IndexError) as exc:  # not the landmarks: a pose or a depth field without support
        raise RuntimeError(
            f"frame {index}: the window's system stayed indeterminate after every landmark got a "
            f"depth prior ({str(exc).strip().splitlines()[0]})"
        ) from exc
