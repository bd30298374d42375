"""Motion stereo: corners outside a cone LiDAR's reach get their depth from the frames before and after,
with each pair's length set by the LiDAR; lone or contradicted corners and unreadable neighbours are left out."""

from __future__ import annotations

import numpy as np
import pytest

from leovr.config import SimulateConfig
from leovr.data import open_sequence
from leovr.lidar.projection import sparse_depth
from leovr.sim.simulate import simulate
from odometry.corner_correction import corrected_depth
from odometry.frame_tracks import GrayImages
from odometry.motion_stereo import (
    LIDAR_GAP_PX,
    Corners,
    agree_with_neighbours,
    motion_stereo_depth,
    neighbour_frames,
)
from scipy.ndimage import distance_transform_edt

OFFSETS = [1, 2, 3, 4]  # a 9-frame drive


@pytest.fixture(scope="module")
def drive(straight_mid40_drive):
    return straight_mid40_drive


def _run(drive, own_scale: float = 1.0, load=None):
    seq, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape) * own_scale
    images = GrayImages(load or (lambda j: frames[j].image), keep=16)
    return (
        f,
        own,
        motion_stereo_depth(4, neighbour_frames(4, list(range(9)), OFFSETS), images, f.K, own),
    )


def test_corners_outside_the_cone_take_their_true_depth(drive):
    f, own, out = _run(drive)
    v, u = np.nonzero(out > 0)
    assert len(v) >= 20
    assert (distance_transform_edt(own <= 0)[v, u] > LIDAR_GAP_PX).all()  # never beside a return
    rel = np.abs(out[v, u] - f.depth[v, u]) / f.depth[v, u]
    assert np.median(rel) < 0.08 and np.mean(rel < 0.3) > 0.85


def test_the_lidar_sets_the_length(drive):
    _, _, out = _run(drive)
    _, _, doubled = _run(drive, own_scale=2.0)
    both = (out > 0) & (doubled > 0)
    assert both.sum() >= 20
    assert np.median(doubled[both] / out[both]) == pytest.approx(2.0, rel=0.02)


def test_no_returns_or_no_readable_neighbour_gives_no_corners(drive):
    _, own, _ = _run(drive, own_scale=0.0)
    _, _, out = _run(drive, own_scale=0.0)
    assert not (out > 0).any()
    seq, frames = drive
    _, _, out = _run(drive, load=lambda j: frames[j].image if j == 4 else None)  # every neighbour unreadable
    assert not (out > 0).any()
    _, _, some = _run(drive, load=lambda j: None if j in (3, 5) else frames[j].image)  # two left out, the rest used
    assert (some > 0).sum() >= 10


def test_lone_and_contradicted_corners_are_dropped():
    u = np.array([100, 104, 108, 112, 300, 106])
    v = np.array([50, 52, 50, 52, 200, 51])
    z = np.array([20.0, 20.5, 19.8, 20.2, 20.0, 40.0])  # a lone corner at (300, 200); an outlier among the rest
    c = Corners(u, v, z, np.zeros(6), np.full(6, 10.0), np.full(6, 4))
    keep = agree_with_neighbours(c, radius_px=30.0, min_neighbours=2, max_log_diff=0.15)
    assert keep.tolist() == [True, True, True, True, False, False]
    assert agree_with_neighbours(c, 30.0, 0, 0.15).all()  # switched off


def test_corrected_depth_moves_the_depth_around_corners_only():
    depth = np.full((100, 200), 10.0, np.float32)
    corners = np.zeros_like(depth)
    corners[40:60:4, 20:40:4] = 40.0  # 25 corners at 4x the generator's depth
    out = corrected_depth(depth, corners, sigma_px=6.0, support=1.0)
    assert out[50, 30] > 30.0  # among them: near the corners' depth
    assert out[50, 180] == pytest.approx(10.0, rel=1e-4)  # far from them: unchanged
    lone = np.zeros_like(depth)
    lone[50, 100] = 40.0
    assert 15.0 < corrected_depth(depth, lone, 6.0, 1.0)[50, 100] < 25.0  # one corner: half way (in log)


def test_corrected_depth_keeps_a_corner_on_its_own_surface():
    """A far corner that lands on a thin near object (a pole at 3 m in front of a 70 m facade) must not
    carry its 23x ratio onto the facade around it (a real run once put 60-80 m pixels at hundreds of metres)."""
    depth = np.full((100, 200), 70.0, np.float32)
    depth[:, 98:103] = 3.0  # the generator's pole
    corners = np.zeros_like(depth)
    corners[30:70:8, 101] = 70.0  # corners of the facade's texture, a pixel inside the generator's pole edge
    plain = corrected_depth(depth, corners, sigma_px=6.0, support=1.0)
    assert plain.max() > 300.0  # without the range weight: the facade blown up
    out = corrected_depth(depth, corners, 6.0, 1.0, range_log=0.2)
    facade = np.ones(depth.shape, bool)
    facade[:, 98:103] = False
    assert out[facade].max() < 71.0 and out[facade].min() > 69.0  # the facade keeps its depth
    edge = corrected_depth(depth, corners, 6.0, 1.0, range_log=0.2, edge_px=2)  # the corner joins the facade
    assert np.allclose(edge, depth, rtol=1e-4)


@pytest.mark.slow
def test_refine_runs_motion_stereo_with_a_cone_lidar_only(drive, tmp_path, monkeypatch):
    import odometry.motion_stereo as ms
    from leovr.config import RefineConfig
    from leovr.data.io import read_depth_png
    from leovr.pipeline.refine import run_refine

    seq, _ = drive
    calls = []
    real = ms.motion_stereo_depth
    monkeypatch.setattr(ms, "motion_stereo_depth", lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    run_refine(seq, RefineConfig(input="full"), tmp_path / "auto", progress=False)
    # a Mid-40 cone: every frame (offsets 2, 4, 8 of the shipped ones: frames 2-6 have 4 views or more)
    assert calls == list(range(9))
    calls.clear()
    run_refine(seq, RefineConfig(input="full", motion_stereo={"enabled": False}), tmp_path / "off", progress=False)
    assert calls == []
    moved = [
        np.abs(
            read_depth_png(tmp_path / "auto" / "depth_generator" / f"{i:06d}.png")
            - read_depth_png(tmp_path / "off" / "depth_generator" / f"{i:06d}.png")
        ).max()
        for i in range(9)
    ]
    assert max(moved) > 1.0  # the corners corrected the generator's depth
    spinning = tmp_path / "vlp16"
    simulate(SimulateConfig(scenario="straight", lidar="vlp16", frames=3, seed=21), spinning, progress=False)
    run_refine(open_sequence(spinning), RefineConfig(input="full"), tmp_path / "vlp16_out", progress=False)
    assert calls == []  # a spinning LiDAR sees the whole image


def test_pair_motions_match_the_true_motion_and_take_their_length_from_the_lidar(drive):
    """The images' motion from frame 4 to earlier frames (window graph factors): rotation and direction
    from the tracks, length from the frame's returns; wrong returns give a wrong length."""
    from odometry.frame_tracks import pair_motions

    seq, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    images = GrayImages(lambda j: frames[j].image, keep=16)
    found = pair_motions(4, [3, 2, 1], images, f.K, own)
    assert sorted(found) == [1, 2, 3]
    for j, T in found.items():
        true = np.linalg.inv(frames[j].T_world_cam) @ f.T_world_cam  # camera 4's points into camera j
        d = np.linalg.inv(true) @ T
        angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        length = np.linalg.norm(T[:3, 3]) / np.linalg.norm(true[:3, 3])
        # one frame apart the parallax is small and the length up to ~20 % off (the graph's Huber factor
        # takes it with the pairs two and three frames apart)
        assert angle < 0.15 and abs(length - 1) < (0.25 if j == 3 else 0.08), (j, angle, length)
    doubled = pair_motions(4, [2], images, f.K, own * 2.0)
    assert abs(np.linalg.norm(doubled[2][:3, 3]) / np.linalg.norm(found[2][:3, 3]) - 2.0) < 0.05
    assert pair_motions(4, [2], images, f.K, np.zeros_like(own)) == {}  # no return: no length


def test_returns_at_takes_the_nearest_return_within_the_radius():
    from odometry.frame_tracks import returns_at

    rng = np.random.default_rng(3)
    sparse = np.zeros((40, 60), np.float32)
    idx = rng.choice(sparse.size, 80, replace=False)
    sparse.flat[idx] = rng.uniform(1, 50, 80)
    c = rng.uniform(0, [59, 39], (300, 2)).astype(np.float32)
    got = returns_at(sparse, c, 2.0)
    rv, ru = np.nonzero(sparse > 0)
    q = np.round(c)
    d = np.hypot(q[:, :1] - ru[None], q[:, 1:] - rv[None])  # brute force
    near = d.min(1) <= 2.0
    assert (got > 0).sum() > 30 and ((got > 0) == near).all()
    for n in np.nonzero(near)[0]:  # one of the nearest returns (equal distances: either)
        tied = np.isclose(d[n], d[n].min())
        assert np.isclose(sparse[rv[tied], ru[tied]], got[n]).any()
    assert not returns_at(np.zeros_like(sparse), c, 2.0).any()


def test_frame_tracks_share_the_tracks_of_motion_stereo_and_the_pairs(drive, monkeypatch):
    """Motion stereo and the pair motions of one frame track its corners into each neighbour once, with the
    same results as on their own, whatever the order the neighbours are asked in."""
    import odometry.frame_tracks as ft

    seq, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    images = GrayImages(lambda j: frames[j].image, keep=16)
    neighbours = neighbour_frames(4, list(range(9)), OFFSETS)
    alone = motion_stereo_depth(4, neighbours, images, f.K, own)
    # the pairs alone, asked farthest first: each rung tracks its rung below first
    pairs_alone = ft.pair_motions(
        4, [1, 2, 3], images, f.K, own, tracks=ft.FrameTracks(4, images, f.K, own, neighbours)
    )
    tracked = []
    real_track = ft.track
    monkeypatch.setattr(ft, "track", lambda g0, g1, c: tracked.append(1) or real_track(g0, g1, c))
    tracks = ft.FrameTracks(4, images, f.K, own, neighbours)
    shared = motion_stereo_depth(4, neighbours, images, f.K, own, tracks=tracks)
    pairs = ft.pair_motions(4, [3, 2, 1], images, f.K, own, tracks=tracks)
    assert len(tracked) == len(neighbours)  # frames 3, 2 and 1 are motion stereo's neighbours too
    np.testing.assert_array_equal(shared, alone)
    assert sorted(pairs) == sorted(pairs_alone) == [1, 2, 3]
    for j in pairs:
        np.testing.assert_allclose(pairs[j], pairs_alone[j], atol=1e-9)


def test_a_farther_neighbour_tracks_only_the_corners_its_nearer_one_tracked(drive, monkeypatch):
    """Along motion stereo's neighbours, frame i + 4 is asked only for the corners that reached i + 2 (and
    came back), and so on outwards; the corners kept are about those of tracking every corner everywhere."""
    import odometry.frame_tracks as ft

    seq, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    images = GrayImages(lambda j: frames[j].image, keep=16)
    neighbours = neighbour_frames(4, list(range(9)), [1, 2, 4])
    asked = []
    real_track = ft.track
    monkeypatch.setattr(ft, "track", lambda g0, g1, c: asked.append(len(c)) or real_track(g0, g1, c))
    tracks = ft.FrameTracks(4, images, f.K, own, neighbours)
    ladder = motion_stereo_depth(4, neighbours, images, f.K, own, tracks=tracks)
    n = len(tracks.corners)
    assert asked[:2] == [n, n]  # frames 3 and 5: every corner
    for far, near in ((2, 3), (6, 5), (0, 2), (8, 6)):
        ok_far, ok_near = tracks._track(far)[1], tracks._track(near)[1]
        assert not (ok_far & ~ok_near).any(), (far, near)
    assert max(asked[2:]) < n  # the farther ones: fewer
    every = motion_stereo_depth(4, neighbours, images, f.K, own, tracks=ft.FrameTracks(4, images, f.K, own))
    both = (ladder > 0) & (every > 0)
    assert abs((ladder > 0).sum() - (every > 0).sum()) < 0.15 * (every > 0).sum()
    assert both.sum() > 0.8 * (every > 0).sum()
    np.testing.assert_allclose(ladder[both], every[both], rtol=0.05)
