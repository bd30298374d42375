"""The depth-based mover tests of the photometric mask (selfsup.motion_mask) on scenes rendered here:
a wall and a box in front of it, the camera driving 1 m forward."""

from __future__ import annotations

import numpy as np

from selfsup.motion_mask import PairKeep, depth_disagreement, movers
from selfsup.supervision import mover_keep

K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
H, W = 120, 160


def render(wall_z: float, box_z: float | None, box_x: float = 0.0, half: float = 1.0) -> np.ndarray:
    """Depth of a fronto-parallel wall at `wall_z`, with a square box face (side 2 `half` m, centred
    `box_x` m right of the optical axis) at `box_z` in front of it."""
    depth = np.full((H, W), wall_z)
    if box_z is not None:
        v, u = np.mgrid[0:H, 0:W]
        x = (u - K[0, 2]) / K[0, 0] * box_z
        y = (v - K[1, 2]) / K[1, 1] * box_z
        depth[(np.abs(x - box_x) < half) & (np.abs(y) < half)] = box_z
    return depth


def forward(metres: float) -> np.ndarray:
    """T_j_i of a camera that drove `metres` along its optical axis: points come nearer."""
    T = np.eye(4)
    T[2, 3] = -metres
    return T


def test_static_scene_has_no_depth_disagreement():
    i, j = render(20.0, 10.0), render(19.0, 9.0)  # everything static: 1 m nearer in frame j
    assert depth_disagreement(i, j, forward(1.0), K, rel=0.05).sum() == 0


def test_box_at_ego_speed_and_oncoming_box_disagree():
    box = render(20.0, 10.0) == 10.0
    ahead = depth_disagreement(render(20.0, 10.0), render(19.0, 10.0), forward(1.0), K, rel=0.05)  # keeps its distance
    assert ahead[box].mean() > 0.9 and ahead[~box].mean() < 0.02
    oncoming = depth_disagreement(render(20.0, 10.0), render(19.0, 8.0), forward(1.0), K, rel=0.05)  # 1 m towards us
    assert oncoming[box].mean() > 0.9 and oncoming[~box].mean() < 0.02
    # within the tolerance (a depth 3 % off) nothing is dropped
    assert depth_disagreement(render(20.0, 10.0), render(19.0, 9.27), forward(1.0), K, rel=0.05).sum() == 0


def test_unknown_depth_is_no_evidence():
    i, j = render(20.0, 10.0), render(19.0, 10.0)
    assert depth_disagreement(i, np.zeros_like(j), forward(1.0), K, rel=0.05).sum() == 0
    assert depth_disagreement(np.zeros_like(i), j, forward(1.0), K, rel=0.05).sum() == 0


def test_movers_keep_regions_both_tests_confirm():
    a = np.zeros((H, W), bool)
    b = np.zeros((H, W), bool)
    a[10:30, 10:30] = True  # a blob that one test drops, where the other drops a part of it
    b[20:25, 20:40] = True
    a[60:80, 100:120] = True  # a blob only one test drops: not confirmed
    out = movers(a, b)
    assert out[10:30, 10:30].all() and out[20:25, 30:40].all()
    assert not out[60:80, 100:120].any()
    one = np.ones((H, W), bool)
    t = PairKeep(one, one, ~a, ~b)
    assert (mover_keep(t, True, True) == ~out).all()
    assert (mover_keep(t, True, False) == ~a).all() and (mover_keep(t, False, True) == ~b).all()
    assert mover_keep(t, False, False).all()


def test_keep_mask_follows_the_switches():
    from leovr.config import SelfSupConfig
    from selfsup.supervision import keep_mask

    one = np.ones((H, W), bool)
    inside, epi, rig, dep = one.copy(), one.copy(), one.copy(), one.copy()
    inside[:, :5] = False
    epi[50:55, :] = False
    rig[10:30, 10:30] = False
    dep[20:25, 20:40] = False
    dep[90:100, 90:100] = False  # only the depth test: dropped when it runs alone, not under the hysteresis
    t = PairKeep(inside, epi, rig, dep)

    def keep(**switches):
        return keep_mask(t, SelfSupConfig(**switches))

    assert (keep(flow_mask=False, rigid_mask=False, depth_mask=False) == inside).all()
    assert (keep(rigid_mask=False, depth_mask=False) == (inside & epi)).all()
    assert (keep() == (inside & epi & rig)).all()  # the defaults: eq. 19 and the rigid test, not the depth test
    assert (keep(rigid_mask=False, depth_mask=True) == (inside & epi & dep)).all()
    both = keep(depth_mask=True)
    assert not both[10:30, 10:30].any() and not both[20:25, 30:40].any() and both[90:100, 90:100].all()


def test_resume_check_counts_a_missing_setting_as_its_default():
    from leovr.config import SelfSupConfig
    from leovr.depth.train_state import config_changes

    saved = SelfSupConfig().model_dump()
    del saved["depth_mask"]  # a run begun before the setting existed
    assert config_changes(saved, SelfSupConfig()) == []
    assert config_changes(saved, SelfSupConfig(depth_mask=True)) == ["depth_mask"]
    assert config_changes({**saved, "lr": 0.5}, SelfSupConfig()) == ["lr"]
