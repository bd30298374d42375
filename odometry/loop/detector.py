"""Loop candidates as LeoVR describes (Sec. IV-B): the lowest similarity between frame i and its
co-visible neighbours is the bar; earlier, non-neighbouring frames scoring above it are candidates;
a loop is proposed only after the best candidate stays consistent for more than three frames."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np


@dataclass
class BowDatabase:
    """Bag-of-words vectors of past frames with an inverted index (word -> frames, weights)."""

    index: dict[int, list[tuple[int, float]]] = field(default_factory=lambda: defaultdict(list))
    vectors: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def add(self, frame: int, bow: tuple[np.ndarray, np.ndarray]) -> None:
        self.vectors[frame] = bow
        for w, v in zip(*bow):
            self.index[int(w)].append((frame, float(v)))

    def query(self, bow: tuple[np.ndarray, np.ndarray]) -> dict[int, float]:
        """L1 score (sum of shared-word minima) against every stored frame that shares a word."""
        scores: dict[int, float] = defaultdict(float)
        for w, v in zip(*bow):
            for f, u in self.index.get(int(w), ()):
                scores[f] += min(v, u)
        return scores


@dataclass
class LoopDetector:
    neighbours: int = 3  # co-visible frames before i that set the bar
    min_gap: int = 30  # candidates must be at least this many frames older
    min_score: float = 0.05
    consistent: int = 3  # accepted after more than this many consecutive consistent frames
    group: int = 5  # candidates within this many frames of the previous one are "consistent"
    db: BowDatabase = field(default_factory=BowDatabase)
    _streak: int = 0
    _last: int | None = None

    def add(self, frame: int, bow: tuple[np.ndarray, np.ndarray]) -> tuple[int, float] | None:
        """Score frame against the database, then store it; returns (candidate frame, score) once a
        candidate has stayed consistent for more than `consistent` frames, else None."""
        scores = self.db.query(bow)
        neigh = [scores.get(j, 0.0) for j in range(frame - self.neighbours, frame) if j in self.db.vectors]
        self.db.add(frame, bow)
        bar = max(min(neigh), self.min_score) if neigh else None
        best = None
        if bar is not None:
            old = {j: s for j, s in scores.items() if j <= frame - self.min_gap and s > bar}
            if old:
                j = max(old, key=old.get)
                best = (j, old[j])
        if best is None:
            self._streak, self._last = 0, None
            return None
        ok = self._last is not None and abs(best[0] - self._last) <= self.group
        self._streak = self._streak + 1 if ok else 1
        self._last = best[0]
        return best if self._streak > self.consistent else None
