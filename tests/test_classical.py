"""Classical completion: nearest fill and IP-Basic."""

from __future__ import annotations

import numpy as np

from leovr.depth.classical import fill_top, ipbasic, nearest_fill
from leovr.depth.fills import complete_depth


def test_nearest_fill_takes_the_closest_sample():
    s = np.zeros((5, 10), np.float32)
    s[2, 1], s[2, 8] = 3.0, 7.0
    d = nearest_fill(s)
    assert (d[:, :4] == 3.0).all() and (d[:, 6:] == 7.0).all()


def test_fill_top_extends_each_column_upwards():
    d = np.zeros((4, 3), np.float32)
    d[2, 0], d[1, 2], d[3, 2] = 5.0, 6.0, 9.0
    out = fill_top(d)
    assert list(out[:, 0]) == [5, 5, 5, 0] and list(out[:, 1]) == [0, 0, 0, 0] and list(out[:, 2]) == [6, 6, 0, 9]


def test_ipbasic_completes_a_wall_and_keeps_near_object_edges():
    h, w = 120, 200
    truth = np.full((h, w), 20.0, np.float32)
    truth[40:100, 60:120] = 8.0  # a box in front of the wall
    sparse = np.zeros_like(truth)
    sparse[::4, ::3] = truth[::4, ::3]  # a scan-line pattern, like a LiDAR
    d = ipbasic(sparse)
    assert (d > 0).all()
    err = np.abs(d - truth)
    assert np.median(err) < 0.01
    assert err[50:90, 70:110].max() < 0.05 and err[:30].max() < 0.05  # interiors exact
    assert (err > 1.0).mean() < 0.05  # only a thin band at the box edges is wrong
    assert np.abs(complete_depth(sparse, "nearest") - truth).mean() < 1.0
