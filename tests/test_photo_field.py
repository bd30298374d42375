"""The photometric correction of a leaving frame: where no LiDAR return lies, the images of the frames before
and after pick the depth; nodes with returns, untextured or unseen ones keep the graph's depth."""

from __future__ import annotations

import numpy as np
import pytest

from leovr.geometry import invert_T
from leovr.lidar.projection import sparse_depth
from odometry.depth_field import CorrectionGrid
import odometry.photo_field as pf
from odometry.photo_field import COLS, ROWS, free_nodes, photometric_correction, photometric_offsets


@pytest.fixture(scope="module")
def drive(straight_mid40_drive):
    return straight_mid40_drive


def _gray(f):
    import cv2

    return cv2.cvtColor(f.image, cv2.COLOR_RGB2GRAY)


def _neighbours(frames, i=4, offsets=(1, 2, 3)):
    T_i = frames[i].T_world_cam
    return [(_gray(frames[j]), invert_T(frames[j].T_world_cam) @ T_i) for o in offsets for j in (i - o, i + o)]


def test_a_wrong_scale_outside_the_cone_comes_back_to_the_truth(drive):
    _, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    free = free_nodes(own)
    assert 0.3 < free.mean() < 0.95  # the cone's nodes hold returns, the rest of the image none
    grid = CorrectionGrid(ROWS, COLS, *f.shape)
    shift = grid.upsample(0.3 * free)  # the free nodes' depth 35 % too far
    wrong = np.where(f.depth > 0, f.depth * np.exp(shift), 0.0)
    off = photometric_offsets(wrong, _gray(f), _neighbours(frames), f.K, free)
    assert np.all(off[~free] == 0)  # nodes with returns never move
    fixed = photometric_correction(wrong, off)
    region = (shift > 0.29) & (f.depth > 0) & (f.depth < 80)
    before = np.abs(wrong[region] - f.depth[region]).mean()
    after = np.abs(fixed[region] - f.depth[region]).mean()
    assert after < 0.5 * before
    assert np.median(off[free & (off != 0)]) == pytest.approx(-0.3, abs=0.08)
    # the right depth stays where it is: few nodes move, and its error stays far below the wrong one's
    kept = photometric_offsets(f.depth, _gray(f), _neighbours(frames), f.K, free)
    assert np.mean(np.abs(kept[free]) > 0.1) < 0.05
    assert np.abs(photometric_correction(f.depth, kept)[region] - f.depth[region]).mean() < 0.25 * before


def test_no_neighbour_no_free_node_or_a_flat_image_moves_nothing(drive):
    _, frames = drive
    f = frames[4]
    free = np.ones(ROWS * COLS, bool)
    depth = f.depth * 1.3
    assert not photometric_offsets(depth, _gray(f), [], f.K, free).any()
    assert not photometric_offsets(depth, _gray(f), _neighbours(frames), f.K, ~free).any()
    flat = np.full(f.shape, 128, np.uint8)
    assert not photometric_offsets(depth, flat, [(flat, np.eye(4))], f.K, free).any()
    assert photometric_correction(depth, np.zeros(ROWS * COLS)) is depth


@pytest.mark.slow
def test_refine_runs_it_with_a_cone_lidar_and_can_be_turned_off(drive, tmp_path, monkeypatch):
    import odometry.photo_field as pf
    from leovr.config import RefineConfig
    from leovr.data.io import read_depth_png
    from leovr.pipeline.refine import run_refine

    seq, _ = drive
    calls = []
    real = pf.photometric_offsets
    monkeypatch.setattr(pf, "photometric_offsets", lambda *a, **k: calls.append(len(a[2])) or real(*a, **k))
    run_refine(seq, RefineConfig(input="full", end=7), tmp_path / "on", progress=False, score=False)
    assert len(calls) == 7 and min(calls) == 3 and max(calls) == 6  # every frame; its neighbours within 3 frames
    calls.clear()
    run_refine(
        seq,
        RefineConfig(input="full", end=7, photometric={"enabled": False}),
        tmp_path / "off",
        progress=False,
        score=False,
    )
    assert calls == []

    def png(run: str, kind: str, i: int) -> np.ndarray:
        return read_depth_png(tmp_path / run / kind / f"{i:06d}.png")

    assert all(np.array_equal(png("on", "depth_generator", i), png("off", "depth_generator", i)) for i in range(7))
    assert any(not np.array_equal(png("on", "depth", i), png("off", "depth", i)) for i in range(7))


def test_poses_whose_steps_read_short_are_caught_by_the_nodes_with_returns(drive):
    _, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    free = free_nodes(own)
    short = []
    for im, T in _neighbours(frames):
        T = T.copy()
        T[:3, 3] *= 0.75  # every step 25 % short: the sweep would read every depth 25 % near
        short.append((im, T))
    stats: dict = {}
    assert not photometric_offsets(f.depth, _gray(f), short, f.K, free, stats).any()
    assert stats["bias"] == pytest.approx(np.log(0.75), abs=0.1)
    stats.clear()
    assert photometric_offsets(f.depth, _gray(f), _neighbours(frames), f.K, free, stats).size == free.size
    assert abs(stats["bias"]) <= pf.MAX_BIAS_LOG and stats["backed"] >= pf.MIN_BACKED


def test_texture_that_moves_with_the_camera_is_not_pushed_away(drive, monkeypatch):
    """A vehicle driving along with the camera stays put in the image: every candidate of the span matches it
    worse than infinity, and without the far candidate its nodes went to the span's far end."""
    _, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    free = free_nodes(own)
    w = f.shape[1] // 4
    along = []
    for im, T in _neighbours(frames):
        im = im.copy()
        im[:, :w] = _gray(f)[:, :w]  # the left quarter: the same picture in every frame
        along.append((im, T))
    node_u = np.tile(np.linspace(0, f.shape[1] - 1, COLS), ROWS)
    region = free & (node_u < 0.7 * w)
    assert region.sum() >= 10
    off = photometric_offsets(f.depth, _gray(f), along, f.K, free)
    with monkeypatch.context() as m:
        m.setattr(pf, "FAR_LOG", 0.0)
        naive = photometric_offsets(f.depth, _gray(f), along, f.K, free)
    assert np.median(naive[region]) > 0.3  # the naive sweep pushes it far
    assert np.mean(np.abs(off[region]) > 0.1) < 0.2


def test_a_frame_whose_known_depth_the_images_do_not_pin_keeps_its_depth(drive, monkeypatch):
    """Most nodes with returns must find a clear valley: where the images do not pin the depth that the LiDAR
    measured, the sweep's choices elsewhere are not trusted either (the real KITTI clip: a quarter of them)."""
    _, frames = drive
    f = frames[4]
    own = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    free = free_nodes(own)
    grid = CorrectionGrid(ROWS, COLS, *f.shape)
    wrong = np.where(f.depth > 0, f.depth * np.exp(grid.upsample(0.3 * free)), 0.0)
    cone = grid.upsample((~free).astype(float)) > 0.3
    cols = np.nonzero(cone.any(0))[0]
    cone[:, int(np.percentile(cols, 80)) :] = False  # the cone's right part stays as it is: a few nodes still pin it
    rng = np.random.default_rng(0)
    unpinned = []
    for im, T in _neighbours(frames):
        im = im.copy()
        im[cone] = rng.integers(0, 256, int(cone.sum()))  # there the neighbours show noise: no depth fits
        unpinned.append((im, T))
    stats: dict = {}
    assert not photometric_offsets(wrong, _gray(f), unpinned, f.K, free, stats).any(), stats
    assert stats["backed"] < pf.MIN_BACKED_SHARE * stats["eligible"]
    # the share test is what refused it: without it the free nodes move as in the first test
    monkeypatch.setattr(pf, "MIN_BACKED_SHARE", 0.0)
    off = photometric_offsets(wrong, _gray(f), unpinned, f.K, free)
    assert np.median(off[free & (off != 0)]) == pytest.approx(-0.3, abs=0.1)


def test_far_coordinates_are_brought_back_to_the_samples_opencv_takes_there():
    """A point behind the camera lands 1e5-1e8 px outside the image; OpenCV reflects such a coordinate back one
    period at a time (slow), so the sweep hands it the coordinate within a period that samples the same."""
    import cv2

    from odometry.photo_field import _reflected

    rng = np.random.default_rng(0)
    h, w = 12, 40
    image = rng.uniform(0, 255, (h, w)).astype(np.float32)
    u = np.concatenate(
        [rng.uniform(-w, 2 * w, 200), rng.uniform(-1e8, 1e8, 200), [-4e6 + 0.25, 3e7 + 0.5, -w - 0.5, 2 * w]]
    )
    u = u.astype(np.float32).reshape(1, -1)
    v = np.full_like(u, 5.5)
    brought = _reflected(u, w)
    assert (brought >= -w).all() and (brought < 2 * w).all()
    np.testing.assert_array_equal(brought[:, :200], u[:, :200])  # near the image: untouched
    sample = lambda x: cv2.remap(image, x, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)  # noqa: E731
    np.testing.assert_array_equal(sample(brought), sample(u))
