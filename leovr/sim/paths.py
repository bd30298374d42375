"""Smooth 2-D paths with arc-length parametrisation (vectorized pose lookup)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d


class Path2D:
    """A polyline resampled every `step` metres and smoothed over `smooth` metres; `pose(s)` gives
    position and heading at arc length s.

    Closed paths wrap around; open paths either clamp at the ends or, with `pingpong`, walk back.
    """

    def __init__(self, points: np.ndarray, closed: bool = False, step: float = 0.05, smooth: float = 0.5) -> None:
        pts = np.asarray(points, np.float64)
        if closed:
            pts = np.vstack([pts, pts[:1]])
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(s[-1])
        self.closed = closed
        self.step = step
        self.s = np.arange(0.0, self.length, step)
        xy = np.stack([np.interp(self.s, s, pts[:, 0]), np.interp(self.s, s, pts[:, 1])], 1)
        # smooth along the arc so position and heading are continuous (a vehicle cannot turn in steps)
        sigma = max(smooth / step, 1e-6)
        pad = 0
        if not closed and len(xy) > 1:  # extend straight beyond the ends so smoothing keeps them in place
            pad = int(4 * sigma) + 1
            k = np.arange(1, pad + 1)[:, None]
            xy = np.vstack([xy[0] - k[::-1] * (xy[1] - xy[0]), xy, xy[-1] + k * (xy[-1] - xy[-2])])
        mode = "wrap" if closed else "nearest"
        sm = gaussian_filter1d(xy, sigma, axis=0, mode=mode)
        d = gaussian_filter1d(xy, sigma, axis=0, order=1, mode=mode)
        end = len(xy) - pad
        self.xy = sm[pad:end]
        self.yaw = np.unwrap(np.arctan2(d[pad:end, 1], d[pad:end, 0]))

    def pose(self, s: np.ndarray, pingpong: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(N x 2 positions, N headings in radians) at arc lengths s."""
        s = np.asarray(s, np.float64)
        flip = np.zeros(s.shape, bool)
        if self.closed:
            s = np.mod(s, self.length)
        elif pingpong:
            period = np.mod(s, 2 * self.length)
            flip = period > self.length
            s = np.where(flip, 2 * self.length - period, period)
        s = np.clip(s, 0.0, self.s[-1])
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        if self.closed:  # close the heading table: the loop ends at the start heading plus whole turns
            turns = np.round((self.yaw[-1] - self.yaw[0]) / (2 * np.pi))
            yaw = np.interp(s, np.append(self.s, self.length), np.append(self.yaw, self.yaw[0] + 2 * np.pi * turns))
        else:
            yaw = np.interp(s, self.s, self.yaw)
        yaw = np.where(flip, yaw + np.pi, yaw)
        return np.stack([x, y], -1), yaw

    def offset(self, lateral: float) -> "Path2D":
        """A parallel path `lateral` metres to the left (negative: right) of this one."""
        normal = np.stack([-np.sin(self.yaw), np.cos(self.yaw)], 1)
        return Path2D((self.xy + lateral * normal)[:: self._stride()], self.closed, self.step)

    def reversed(self) -> "Path2D":
        """The same path driven the other way."""
        return Path2D(self.xy[::-1][:: self._stride()], self.closed, self.step)

    def _stride(self) -> int:
        """Keep a vertex every 0.5 m when deriving a path (it is resampled and smoothed again)."""
        return max(1, int(round(0.5 / self.step)))


def rounded_rectangle(x0: float, y0: float, x1: float, y1: float, radius: float, n_arc: int = 24) -> np.ndarray:
    """Counter-clockwise rectangle with circular corners, as a point list (closed implicitly)."""
    corners = [
        (x1 - radius, y0 + radius, -np.pi / 2),
        (x1 - radius, y1 - radius, 0.0),
        (x0 + radius, y1 - radius, np.pi / 2),
        (x0 + radius, y0 + radius, np.pi),
    ]
    pts = []
    for cx, cy, a0 in corners:
        a = a0 + np.linspace(0.0, np.pi / 2, n_arc)
        pts.append(np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a)], 1))
    return np.vstack(pts)
