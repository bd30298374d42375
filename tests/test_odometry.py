"""Front end and graph pieces: correction field, LiDAR association, PnP / pose choice, and the
depth-consistency residual with its analytic Jacobians."""

from __future__ import annotations

import pytest
import cv2
import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from leovr.geometry import invert_T, make_T
from odometry.depth_field import CorrectionGrid, bilinear
from odometry.factors import DepthConsistency, FrameDepth
from odometry.initial_pose import choose_pose, pnp_pose, registration_covariance
from odometry.lidar_assoc import associate
from tests.conftest import needs_shared

K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])
SHAPE = (120, 160)


def test_correction_grid_interpolates_nodes_and_constants():
    g = CorrectionGrid(4, 5, *SHAPE)
    c = np.arange(g.size, dtype=float)
    # node (row 1, col 2) sits at pixel (u, v) = (2 * 159 / 4, 1 * 119 / 3)
    assert np.isclose(g.offsets(c, np.array([2 * 159 / 4]), np.array([119 / 3]))[0], 1 * 5 + 2)
    assert np.allclose(g.upsample(np.full(g.size, 0.3)), 0.3)
    u, v = np.random.default_rng(0).uniform(0, 159, 50), np.random.default_rng(1).uniform(0, 119, 50)
    assert np.allclose(g.dense_weights(u, v) @ c, g.offsets(c, u, v))
    assert np.allclose(g.dense_weights(u, v).sum(1), 1.0)
    # the separable upsampling is the bilinear interpolation at every pixel
    c = np.random.default_rng(2).normal(size=g.size)
    gv, gu = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    np.testing.assert_allclose(g.upsample(c), g.offsets(c, gu.ravel(), gv.ravel()).reshape(SHAPE), atol=1e-12)


def test_correction_grid_cell_means_average_the_pixels_nearest_each_node_ignoring_nans():
    g = CorrectionGrid(4, 5, *SHAPE)
    gv, gu = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    # each pixel holds the index of its nearest node, (row, col) = (round(v * 3 / 119), round(u * 4 / 159))
    nearest = np.rint(gv * 3 / 119) * 5 + np.rint(gu * 4 / 159)
    np.testing.assert_array_equal(g.cell_means(nearest), np.arange(g.size))
    noisy = nearest + np.where((gu + gv) % 2, 1.0, -1.0)  # +-1 in a checkerboard: the means stay
    noisy[gv < 10] = np.nan  # the top row of nodes keeps rows 10-19; NaNs are left out
    np.testing.assert_allclose(g.cell_means(noisy), np.arange(g.size), atol=0.05)
    assert np.isnan(g.cell_means(np.full(SHAPE, np.nan))).all()


def test_lidar_association_nearest_within_radius_and_rejects_discontinuities():
    lidar_uv = np.array([[10.0, 10.0], [50.0, 50.0], [52.0, 50.0], [100.0, 100.0]])
    depth = np.array([5.0, 8.0, 20.0, 12.0])  # 50/52: an edge between 8 m and 20 m
    uv = np.array([[11.0, 12.0], [51.0, 50.0], [100.0, 106.0], [300.0, 300.0]])
    z = associate(uv, lidar_uv, depth, radius_px=5.0, max_rel_spread=0.1)
    assert z[0] == 5.0 and np.isnan(z[1]) and np.isnan(z[2]) and np.isnan(z[3])


def test_pnp_recovers_pose_and_choice_prefers_the_consistent_candidate():
    rng = np.random.default_rng(0)
    T = make_T(Rotation.from_rotvec([0.02, -0.05, 0.01]).as_matrix(), [0.3, -0.1, 1.2])
    cam = np.c_[rng.uniform(-8, 8, 80), rng.uniform(-4, 4, 80), rng.uniform(6, 40, 80)]
    world = cam @ T[:3, :3].T + T[:3, 3]
    uv = (cam @ K.T)[:, :2] / cam[:, 2:]
    uv[:10] += 30.0  # outliers
    est, inl = pnp_pose(world, uv, K)
    assert est is not None and np.allclose(est, T, atol=1e-3) and not inl[:10].any() and inl[10:].all()
    guess = choose_pose({"icp": make_T(t=[1.0, 0, 0]) @ T, "pnp": est}, world, uv, K)
    assert guess.source == "pnp" and guess.inliers == 70


def _plane_depth(T_world_cam: np.ndarray, n=np.array([0.0, -0.2, -1.0]), d=30.0) -> np.ndarray:
    """Depth of the plane n.X + d = 0 (world) seen from the camera."""
    v, u = np.mgrid[0 : SHAPE[0], 0 : SHAPE[1]]
    rays = np.stack([u, v, np.ones_like(u)], -1).reshape(-1, 3) @ np.linalg.inv(K).T
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    s = -(n @ t + d) / (rays @ R.T @ n)
    return s.reshape(SHAPE)


def test_an_initial_pose_whose_step_jumps_from_the_last_steps_gives_way_to_one_that_does_not():
    """With LiDAR the initial pose is the candidate that reprojects the most matches; a candidate whose step is far
    longer or shorter than the last three initial steps' median (a PnP on matches of one depth, a registration that
    slipped) is left out while another holds, and kept when none does."""
    from leovr.config import RefineConfig
    from odometry.frontend import FrontEnd

    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    front = FrontEnd(RefineConfig(input="vlp16"), K, (480, 640), np.eye(4))
    T_prev = make_T(Rotation.from_euler("y", 30, degrees=True).as_matrix(), np.array([5.0, 0.0, 40.0]))

    def step(length: float, yaw_deg: float = 0.0) -> np.ndarray:
        return T_prev @ make_T(Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix(), np.array([0, 0, length]))

    cands = {"icp": step(2.3, 6.0), "pnp": step(5.5)}
    assert front._plausible(cands, T_prev) == cands  # no steps measured yet: every candidate stands
    front._step_lengths = [2.2, 2.25, 2.2]
    assert list(front._plausible(cands, T_prev)) == ["icp"]
    both_off = {"icp": step(0.4), "pnp": step(5.5)}
    assert front._plausible(both_off, T_prev) == both_off
    front._step_lengths = [0.1, 0.1, 0.12]  # creeping: at least 0.3 m of change is allowed
    assert list(front._plausible({"icp": step(0.35), "pnp": step(0.5)}, T_prev)) == ["icp"]


def test_an_initial_pose_that_turns_otherwise_than_the_images_gives_way_to_one_that_turns_as_they_do():
    """A PnP on biased depths can reproject every match from a pose a degree off in yaw and win over KISS-ICP's
    step; from there the window's robust kernels take the images' tight pair factors for outliers (the real drive's
    frames 65-67, Mid-40-like). With the images' pair motion from the previous frame, a candidate turning more than
    INIT_GATE_DEG away from it is passed over while another turns as the images do; all stand when none does."""
    from types import SimpleNamespace

    from leovr.config import RefineConfig
    from odometry.frontend import FrontEnd
    from odometry.motion_gates import INIT_GATE_DEG, turning_as_the_images

    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    front = FrontEnd(RefineConfig(input="mid40"), K, (480, 640), np.eye(4))
    T_prev = make_T(Rotation.from_euler("y", 10, degrees=True).as_matrix(), np.array([2.0, 0.0, 20.0]))

    def step(yaw_deg: float, x: float = 0.0) -> np.ndarray:
        return make_T(Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix(), np.array([x, 0, 1.1]))

    truth, off = step(0.2), step(1.4, -0.6)  # the true step; PnP's, 1.2 degrees and 0.6 m off
    rng = np.random.default_rng(1)
    cam = np.c_[rng.uniform(-8, 8, 120), rng.uniform(-3, 3, 120), rng.uniform(8, 40, 120)]  # in PnP's camera
    T_off = T_prev @ off
    obj = cam @ T_off[:3, :3].T + T_off[:3, 3]  # the previous frame's points, placed with biased depths
    img = (cam @ K.T)[:, :2] / cam[:, 2:]
    front.prev = SimpleNamespace(T_icp=np.eye(4))
    T, source = front._lidar_pose(T_prev, truth, obj, img)
    assert source == "pnp" and np.allclose(invert_T(T_prev) @ T, off, atol=1e-3)  # every match reprojects
    T, source = front._lidar_pose(T_prev, truth, obj, img, images_step=step(0.25))
    assert source == "icp" and np.allclose(invert_T(T_prev) @ T, truth, atol=1e-9)
    T, source = front._lidar_pose(T_prev, truth, obj, img, images_step=step(0.2 + 2 * INIT_GATE_DEG))
    assert source == "pnp"  # neither turns as the images: the reprojection decides
    cands = {"a": T_prev @ step(0.5), "b": None}
    assert turning_as_the_images(cands, T_prev, None) == cands


def test_depth_consistency_vanishes_for_true_geometry_and_jacobians_match_numeric():
    Ti = make_T(t=[0.0, 0.0, 1.0])
    Tj = np.eye(4)
    g = CorrectionGrid(4, 5, *SHAPE)
    di, dj = FrameDepth(np.log(_plane_depth(Ti)), g), FrameDepth(np.log(_plane_depth(Tj)), g)
    dc = DepthConsistency(di, dj, K, 0.05)
    rng = np.random.default_rng(0)
    dc.set_samples(rng.uniform(20, 140, 200), rng.uniform(20, 100, 200))
    zero = np.zeros(g.size)
    r, _, _ = dc.evaluate(Ti, Tj, zero, zero, False)
    assert np.abs(r).max() < 0.05  # bilinear sampling only
    r_bad, _, _ = dc.evaluate(make_T(t=[0.0, 0.0, 2.0]), Tj, zero, zero, False)
    assert np.abs(r_bad).mean() > 0.5
    ci, cj = rng.normal(0, 0.02, g.size), rng.normal(0, 0.02, g.size)
    r0, (Ji, Jj), _ = dc.evaluate(Ti, Tj, ci, cj, True)
    s = r0 / np.where(r0 == 0, 1, dc._residual(Ti, Tj, ci, cj))  # robust scale per pixel
    eps = 1e-5
    for k in (0, 7, 13):
        e = np.zeros(g.size)
        e[k] = eps
        num_i = s * (dc._residual(Ti, Tj, ci + e, cj) - dc._residual(Ti, Tj, ci - e, cj)) / (2 * eps)
        num_j = s * (dc._residual(Ti, Tj, ci, cj + e) - dc._residual(Ti, Tj, ci, cj - e)) / (2 * eps)
        assert np.allclose(Ji[:, k], num_i, atol=0.05 * np.abs(num_i).max() + 1e-6)
        assert np.allclose(Jj[:, k], num_j, atol=1e-4)


def test_depth_consistency_pose_jacobians_match_gtsam_retract():
    """The analytic pose blocks against central differences through gtsam's own Pose3.retract."""
    import gtsam

    Ti = make_T(Rotation.from_rotvec([0.01, -0.03, 0.02]).as_matrix(), [0.2, -0.1, 1.0])
    Tj = make_T(Rotation.from_rotvec([-0.02, 0.01, 0.0]).as_matrix(), [0.0, 0.05, 0.0])
    g = CorrectionGrid(4, 5, *SHAPE)
    di, dj = FrameDepth(np.log(_plane_depth(Ti)), g), FrameDepth(np.log(_plane_depth(Tj)), g)
    dc = DepthConsistency(di, dj, K, 0.05)
    rng = np.random.default_rng(2)
    dc.set_samples(rng.uniform(20, 140, 300), rng.uniform(20, 100, 300))
    ci, cj = rng.normal(0, 0.05, g.size), rng.normal(0, 0.05, g.size)
    r0, (J_Ti, J_Tj, J_ci, J_cj), s = dc.evaluate(Ti, Tj, ci, cj, True, poses=True)
    _, (Ji, Jj), _ = dc.evaluate(Ti, Tj, ci, cj, True)
    assert np.array_equal(Ji, J_ci) and np.array_equal(Jj, J_cj)
    assert J_Ti.shape == J_Tj.shape == (300, 6) and np.abs(J_Ti).max() > 0.1
    eps = 1e-6
    for slot, T in ((0, Ti), (1, Tj)):
        pose = gtsam.Pose3(T)
        for k in range(6):
            d = np.zeros(6)
            d[k] = eps
            Tp, Tm = pose.retract(d).matrix(), pose.retract(-d).matrix()
            if slot == 0:
                num = s * (dc._residual(Tp, Tj, ci, cj) - dc._residual(Tm, Tj, ci, cj)) / (2 * eps)
            else:
                num = s * (dc._residual(Ti, Tp, ci, cj) - dc._residual(Ti, Tm, ci, cj)) / (2 * eps)
            J = (J_Ti, J_Tj)[slot][:, k]
            # the analytic blocks use the smoothed image gradient, the numeric ones the bilinear patch
            assert np.abs(J - num).mean() < 0.05 * np.abs(num).mean() + 1e-6, (slot, k)
            assert np.corrcoef(J, num)[0, 1] > 0.99, (slot, k)


def test_bilinear_matches_linear_ramp():
    img = np.add.outer(np.arange(5.0), 10 * np.arange(6.0))  # v + 10 u
    assert np.allclose(bilinear(img, np.array([2.5, 0.0]), np.array([1.25, 3.0])), [1.25 + 25, 3.0])


def test_registration_covariance_grows_with_residuals_and_a_narrow_spread_of_points():
    rng = np.random.default_rng(0)

    def cov(pts, noise):
        return registration_covariance(pts, pts + rng.normal(0, noise, pts.shape), np.eye(4), 1.0)

    wide = rng.uniform(-20, 20, (2000, 3))
    narrow = np.c_[rng.uniform(-1, 1, (2000, 2)), rng.uniform(10, 30, 2000)]  # a thin cone ahead
    c_wide, c_noisy, c_narrow = cov(wide, 0.02), cov(wide, 0.1), cov(narrow, 0.02)
    assert np.all(np.linalg.eigvalsh(c_wide) > 0)
    assert 15 < c_noisy[3, 3] / c_wide[3, 3] < 40  # variance goes with the residuals' (25x here)
    assert c_narrow[2, 2] > 100 * c_wide[2, 2]  # roll about the cone's axis: hardly any lever arm
    assert cov(wide[:20], 0.02) is None  # too few matches


def test_icp_window_factors_make_the_graph_follow_the_lidar_motion():
    """Frames with no visual factor at all: the ICP motions inside the window must carry the graph
    along the LiDAR trajectory (not the weak front-end motion, which is wrong here)."""
    from leovr.config import RefineConfig
    from odometry.window_graph import FrameInput, WindowGraph

    cfg = RefineConfig(window=4, graph={"depth_factors": False})
    graph = WindowGraph(cfg, K, SHAPE)
    truth = [make_T(Rotation.from_rotvec([0, 0.01 * i, 0]).as_matrix(), [0.1 * i, 0, 1.0 * i]) for i in range(8)]
    cov = np.diag(np.r_[np.full(3, 1e-3), np.full(3, 0.02)] ** 2)
    done = []
    for i, T in enumerate(truth):
        wrong = make_T(t=[0, 0, 0.5 * i])  # the front end's guess: half speed, no turn
        rel = None if i == 0 else np.linalg.inv(make_T(t=[0, 0, 0.5 * (i - 1)])) @ wrong
        f = FrameInput(
            i,
            wrong,
            np.zeros(SHAPE),
            np.full(SHAPE, 0.1),
            [],
            {},
            None,
            None,
            rel,
            None,
            (T, np.zeros((6, 6)) if i == 0 else cov),
        )
        done += graph.add_frame(f)
    done += graph.flush()
    est = {r.index: r.T_world_cam for r in done}
    err = max(np.linalg.norm(est[i][:3, 3] - truth[i][:3, 3]) for i in range(8))
    assert err < 0.1, err


def _icp_frame(i: int, T: np.ndarray, rel, icp: np.ndarray, cov: np.ndarray, pairs: dict):
    """A frame for the window graph with no visual factor: its initial pose and front-end motion, KISS-ICP's pose
    (exact at frame 0, `cov` after) and its pair motions (earlier frame -> T_j_i)."""
    from odometry.window_graph import FrameInput

    icp_pose = (icp, np.zeros((6, 6)) if i == 0 else cov)
    empty = (np.zeros(SHAPE), np.full(SHAPE, 0.1), [], {}, None, None)
    return FrameInput(i, T, *empty, rel, None, icp_pose, pair_motions=pairs)


def test_a_kiss_icp_motion_that_slipped_from_the_images_rotation_is_left_out():
    """KISS-ICP slips by 10 degrees at frame 5 (as a cone LiDAR's registration does in a rendered lap's fast turns)
    while sure of itself: its motions across the slip disagree with the images' rotation and are left out, so the
    poses stay with the images and the front end; the motions after the slip, among themselves right, stay in."""
    from leovr.config import RefineConfig
    from leovr.geometry import rotation_angle_deg
    from odometry.window_graph import WindowGraph

    cfg = RefineConfig(window=4, graph={"depth_factors": False})
    graph = WindowGraph(cfg, K, SHAPE)
    truth = [make_T(Rotation.from_rotvec([0, 0.01 * i, 0]).as_matrix(), [0.1 * i, 0, 1.0 * i]) for i in range(10)]
    slip = make_T(Rotation.from_rotvec([0, np.radians(10.0), 0]).as_matrix())
    cov = np.diag(np.r_[np.full(3, 1e-3), np.full(3, 0.02)] ** 2)
    done = []
    for i, T in enumerate(truth):
        rel = None if i == 0 else np.linalg.inv(truth[i - 1]) @ T
        icp = slip @ T if i >= 5 else T  # its map turned by the slip: later motions among themselves right
        done += graph.add_frame(_icp_frame(i, T, rel, icp, cov, {i - 1: rel} if i else {}))
    done += graph.flush()
    est = {r.index: r.T_world_cam for r in done}
    assert graph.icp_rejected >= 3
    assert max(rotation_angle_deg(est[i][:3, :3].T @ truth[i][:3, :3]) for i in range(10)) < 1.0
    assert max(np.linalg.norm(est[i][:3, 3] - truth[i][:3, 3]) for i in range(10)) < 0.1


def _sliding_icp_run(step_m: float) -> tuple[float, int]:
    """A straight drive of `step_m` a frame whose KISS-ICP motions slide 8 degrees sideways (as a cone's
    registration does along a hedge) while sure of themselves; the images' pair motions to the frames before (every
    one in the window) point straight ahead, and so does the front end. Returns the largest sideways error (m) and
    the motions left out."""
    from leovr.config import RefineConfig
    from odometry.window_graph import WindowGraph

    graph = WindowGraph(RefineConfig(window=3, graph={"depth_factors": False}), K, SHAPE)  # pairs reach each frame
    truth = [make_T(t=[0, 0, step_m * i]) for i in range(10)]
    slide = np.radians(8.0)
    icp = [make_T(t=[step_m * i * np.sin(slide), 0, step_m * i * np.cos(slide)]) for i in range(10)]
    cov = np.diag(np.r_[np.full(3, 1e-3), np.full(3, 0.01)] ** 2)
    done = []
    for i, T in enumerate(truth):
        rel = None if i == 0 else np.linalg.inv(truth[i - 1]) @ T
        pairs = {j: np.linalg.inv(truth[j]) @ T for j in range(max(i - 3, 0), i)}
        done += graph.add_frame(_icp_frame(i, T, rel, icp[i], cov, pairs))
    done += graph.flush()
    est = {r.index: r.T_world_cam for r in done}
    return max(abs(est[i][0, 3] - truth[i][0, 3]) for i in range(10)), graph.icp_rejected


def test_a_kiss_icp_motion_that_slides_from_the_images_direction_is_left_out():
    """Over a baseline of a metre and more the images' direction of travel outweighs a registration that slid
    sideways: its motions are left out and the poses stay on the images' line. Over a short one (a vehicle creeping)
    the essential matrix's direction is the less sure, and KISS-ICP's motions stay in."""
    err, rejected = _sliding_icp_run(1.2)
    assert rejected >= 9 and err < 0.05, (err, rejected)
    err_short, rejected_short = _sliding_icp_run(0.2)
    assert rejected_short == 0 and err_short > 0.05, (err_short, rejected_short)


def test_spinning_lidar_told_from_a_narrow_cone():
    from odometry.initial_pose import is_spinning

    rng = np.random.default_rng(0)
    az = rng.uniform(-np.pi, np.pi, 20000)
    sweep = np.c_[20 * np.cos(az), 20 * np.sin(az), rng.uniform(-2, 2, 20000)]
    x = rng.uniform(5, 60, 5000)  # a 38-degree cone ahead
    cone = np.c_[x, x * rng.uniform(-0.35, 0.35, 5000), x * rng.uniform(-0.35, 0.35, 5000)]
    assert is_spinning(sweep) and not is_spinning(cone)


def _window_run(condition: bool, frames: int = 7) -> tuple[list[np.ndarray], int, list[np.ndarray]]:
    """A camera moving 0.5 m per frame along z past 60 landmarks that every frame sees, exact pixels and a
    noisy initial pose; returns the final poses, the largest factor (keys) the smoother held, the truth."""
    from leovr.config import RefineConfig
    from odometry.window_graph import FrameInput, Observation, WindowGraph

    rng = np.random.default_rng(3)
    pts = np.c_[rng.uniform(-6, 6, 60), rng.uniform(-3, 3, 60), rng.uniform(15, 40, 60)]
    cfg = RefineConfig(window=3, graph={"depth_factors": False})
    g = WindowGraph(cfg, K, SHAPE, rng=np.random.default_rng(0), condition_leaving=condition)
    truth, done, largest = [], [], 0
    for i in range(frames):
        T = make_T(t=[0.0, 0.0, 0.5 * i])
        truth.append(T)
        cam = (pts - T[:3, 3]) @ T[:3, :3]
        uv = (cam @ K.T)[:, :2] / cam[:, 2:]
        obs = [Observation(k, i, uv[k]) for k in range(len(pts))]
        noisy = T @ make_T(Rotation.from_rotvec(rng.normal(0, 0.003, 3)).as_matrix(), rng.normal(0, 0.05, 3))
        fi = FrameInput(
            i,
            noisy if i else T,
            np.full(SHAPE, np.log(20.0)),
            np.full(SHAPE, 0.2),
            obs,
            {k: pts[k] + rng.normal(0, 0.2, 3) for k in range(len(pts))} if i == 0 else {},
            None,
            None,
            None if i == 0 else make_T(t=[0.0, 0.0, 0.5]),
        )
        done += g.add_frame(fi)
        factors = g.smoother.getFactors()
        largest = max(
            [largest] + [len(factors.at(n).keys()) for n in range(factors.size()) if factors.at(n) is not None]
        )
    done += g.flush()
    return [r.T_world_cam for r in sorted(done, key=lambda r: r.index)], largest, truth


def test_leaving_frames_condition_their_observations_instead_of_a_dense_marginal():
    poses, largest, truth = _window_run(condition=True)
    dense_poses, dense_largest, _ = _window_run(condition=False)
    assert dense_largest > 60  # marginalising the observations ties every landmark into one factor
    assert largest <= 6  # conditioned: the marginal factor holds frames only
    for est in (poses, dense_poses):
        err = [np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(est, truth)]
        assert max(err) < 0.02, err


def test_pair_factors_make_the_graph_follow_the_images_motion():
    """Frames with a wrong front-end motion and no other pose evidence: the images' motions to the
    window's earlier frames (`FrameInput.pair_motions`) must carry the graph along the true trajectory;
    without them it stays on the wrong one."""
    from leovr.config import RefineConfig
    from odometry.window_graph import FrameInput, WindowGraph

    truth = [make_T(Rotation.from_rotvec([0, 0.02 * i, 0]).as_matrix(), [0.1 * i, 0, 1.0 * i]) for i in range(8)]

    def run(pairs: bool) -> float:
        graph = WindowGraph(RefineConfig(window=4, graph={"depth_factors": False}), K, SHAPE)
        done = []
        guesses = [make_T(T[:3, :3], [0, 0, 0.5 * i]) for i, T in enumerate(truth)]
        for i, T in enumerate(truth):
            # the front end's guess: the turn right (else the pair gate refuses the pairs), half speed
            wrong = guesses[i]
            rel = None if i == 0 else np.linalg.inv(guesses[i - 1]) @ wrong
            f = FrameInput(i, wrong if i else T, np.zeros(SHAPE), np.full(SHAPE, 0.1), [], {}, None, None, rel)
            if pairs:
                f.pair_motions = {j: np.linalg.inv(truth[j]) @ T for j in (i - 1, i - 2, i - 3) if j >= 0}
            done += graph.add_frame(f)
        done += graph.flush()
        est = {r.index: r.T_world_cam for r in done}
        return max(np.linalg.norm(est[i][:3, 3] - truth[i][:3, 3]) for i in range(8))

    assert run(pairs=True) < 0.05
    assert run(pairs=False) > 1.0


def _pair_run(pair_error_deg: float, gate_deg: float, matches_follow_pair: bool) -> float:
    """A straight drive, 1 m a frame, with the front end right and no other evidence; frame 4's pair motion to
    frame 3 has its rotation `pair_error_deg` off about the vertical axis. Returns frame 4's final rotation error
    (degrees) against the truth. `matches_follow_pair`: the front end's matches with frame 3 moved as the pair says."""
    from leovr.config import RefineConfig
    from leovr.geometry import rotation_angle_deg
    from odometry.window_graph import FrameInput, WindowGraph

    truth = [make_T(t=[0, 0, 1.0 * i]) for i in range(7)]
    bad = make_T(Rotation.from_rotvec([0, np.radians(pair_error_deg), 0]).as_matrix(), [0, 0, 1.0])
    rng = np.random.default_rng(1)
    pts = np.c_[rng.uniform(-8, 8, 150), rng.uniform(-2, 2, 150), rng.uniform(6, 40, 150)]  # frame 3's camera

    def pixels(T_cam: np.ndarray) -> np.ndarray:  # pts seen from camera T_cam (in frame 3's coordinates)
        c = (pts - T_cam[:3, 3]) @ T_cam[:3, :3]
        return (c @ K.T)[:, :2] / c[:, 2:]

    import odometry.motion_gates as gates

    graph = WindowGraph(RefineConfig(window=4, graph={"depth_factors": False}), K, SHAPE)
    done = []
    with pytest.MonkeyPatch.context() as m:
        m.setattr(gates, "PAIR_GATE_DEG", gate_deg)
        for i, T in enumerate(truth):
            rel = None if i == 0 else np.linalg.inv(truth[i - 1]) @ T
            f = FrameInput(i, T, np.zeros(SHAPE), np.full(SHAPE, 0.1), [], {}, None, None, rel)
            if i == 4:
                f.pair_motions = {3: bad}
                f.matches_prev = (3, pixels(np.eye(4)), pixels(bad if matches_follow_pair else rel))
            done += graph.add_frame(f)
        done += graph.flush()
    est = {r.index: r.T_world_cam for r in done}
    return rotation_angle_deg((np.linalg.inv(est[3]) @ est[4])[:3, :3])


def test_a_pair_motion_that_neither_the_front_end_nor_its_matches_support_is_left_out():
    """A fast turn can make the tracks of a pair fail together; the pair's tight rotation sigma would impose
    the wrong rotation (Huber only bounds its pull). Left out when both the initial pose and the essential
    matrix of the front end's matches disagree with it; kept when the matches agree with it instead."""
    assert _pair_run(8.0, gate_deg=0.0, matches_follow_pair=False) > 6.0  # no test: the graph follows the pair
    assert _pair_run(8.0, gate_deg=3.0, matches_follow_pair=False) < 0.5  # refused
    assert _pair_run(8.0, gate_deg=3.0, matches_follow_pair=True) > 6.0  # the matches back it: kept
    assert _pair_run(1.0, gate_deg=3.0, matches_follow_pair=False) > 0.7  # a small disagreement is the pair's to fix


def _turning_drive(yaw_deg: list[float], length_m: list[float] | None = None, seed: int = 0):
    """A spinning scanner's drive through a street of walls, step k turning `yaw_deg[k]` and moving `length_m[k]`
    (2.2 m a frame by default: 80 km/h, as the loop laps). Returns the scans (LiDAR frame), the camera-LiDAR
    extrinsic and the true camera motions between frames."""
    from leovr.geometry import invert_T

    rng = np.random.default_rng(seed)
    parts = [rng.uniform([-60, -60, -1.7], [60, 60, -1.7], (40000, 3))]  # the road, LiDAR axes (x forward, z up)
    for _ in range(40):  # walls at random places and headings
        x0, y0, a, length = (
            rng.uniform(-60, 60),
            rng.choice([-1, 1]) * rng.uniform(7, 30),
            rng.uniform(0, np.pi),
            rng.uniform(3, 15),
        )
        s = rng.uniform(0, length, 1500)
        parts.append(np.c_[x0 + s * np.cos(a), y0 + s * np.sin(a), rng.uniform(-1.7, 6, 1500)])
    world = np.vstack(parts)
    lidar = [np.eye(4)]
    for k, yaw in enumerate(yaw_deg):
        step = 2.2 if length_m is None else length_m[k]
        lidar.append(lidar[-1] @ make_T(Rotation.from_rotvec([0, 0, np.radians(yaw)]).as_matrix(), [step, 0, 0]))
    T_cl = make_T(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]), [0, 0, 0])
    steps = [T_cl @ invert_T(lidar[k - 1]) @ lidar[k] @ invert_T(T_cl) for k in range(1, len(lidar))]  # camera motions
    scans = []
    for T in lidar:
        p = (world - T[:3, 3]) @ T[:3, :3]
        scans.append(p[(np.linalg.norm(p, axis=1) < 40) & (rng.random(len(p)) < 0.5)])
    return scans, T_cl, steps


def test_kiss_icp_predicted_with_the_images_motion_follows_a_turn_that_constant_velocity_misses():
    """A spinning scan entering a 13-degree-per-frame turn after a straight (80 km/h, as the loop laps): KISS-ICP's
    constant-velocity prediction misses the turn by its whole rate, beyond the correspondence distance its
    adaptive threshold has shrunk to on the straight, and it registers about 10 degrees short; predicted with the
    camera's motion (`guess`, here the true one; in a run the sweep's motion read from the images) it follows."""
    from leovr.geometry import invert_T, rotation_angle_deg
    from odometry.initial_pose import LidarOdometry

    scans, T_cl, steps = _turning_drive([0.0] * 5 + [13.0] * 3)  # 13 degrees a frame from frame 6

    def worst_turn_error(predicted: bool) -> float:
        odo, poses = LidarOdometry(T_cl), []
        for k, scan in enumerate(scans):
            guess = steps[k - 1] if k == 1 or (predicted and k) else None  # the first step is given to both
            poses.append(odo.register(scan, guess=guess))
        return max(
            rotation_angle_deg((invert_T(steps[k - 1]) @ invert_T(poses[k - 1]) @ poses[k])[:3, :3])
            for k in range(6, len(scans))
        )

    assert worst_turn_error(predicted=False) > 5.0
    assert worst_turn_error(predicted=True) < 0.5


def test_a_cone_lidars_kiss_icp_follows_a_turn_only_when_predicted_with_the_images_motion():
    """The same street seen through a Mid-40-like cone (38 degrees, forward), entering an 8-degree-per-frame turn at
    80 km/h: with its constant velocity KISS-ICP hardly turns at all (each step about 8 degrees short: the narrow view
    holds too little of the street to pull it round), predicted with the camera's motion it follows the turn. In a run
    the window's gate then left almost every motion of the lost registration out."""
    from leovr.geometry import invert_T, rotation_angle_deg
    from leovr.lidar.cheap_sensor import MID40_FOV_DEG
    from odometry.initial_pose import LidarOdometry

    scans, T_cl, steps = _turning_drive([0.0] * 5 + [8.0] * 3)
    inside = np.cos(np.radians(MID40_FOV_DEG) / 2)  # the cone around the LiDAR's x axis
    cone = [p[p[:, 0] >= inside * np.linalg.norm(p, axis=1)] for p in scans]

    def turn_errors(predicted: bool) -> list[float]:
        odo, poses = LidarOdometry(T_cl), []
        for k, scan in enumerate(cone):
            guess = steps[k - 1] if k == 1 or (predicted and k) else None  # the first step is given to both
            poses.append(odo.register(scan, guess=guess))
        return [
            rotation_angle_deg((invert_T(steps[k - 1]) @ invert_T(poses[k - 1]) @ poses[k])[:3, :3])
            for k in range(6, len(cone))
        ]

    assert min(turn_errors(predicted=False)) > 5.0
    assert max(turn_errors(predicted=True)) < 0.5


def test_kiss_icp_takes_the_guess_at_its_own_step_length():
    """The guess (the sweep's motion read from the images) gives KISS-ICP's prediction its rotation and direction;
    its length stays KISS-ICP's own last step's (one image pair has none, and a registration started from another
    length keeps part of it along a straight road): a guess half again too long registers as the true one."""
    from odometry.initial_pose import LidarOdometry

    scans, T_cl, steps = _turning_drive([0.0, 0.0, 2.0, 4.0, 0.0, 0.0])

    def poses(stretch: float) -> list[np.ndarray]:
        odo, out = LidarOdometry(T_cl), []
        for k, scan in enumerate(scans):
            guess = steps[k - 1].copy() if k else None
            if k > 1:  # the first step is given as it is (KISS-ICP has no step of its own yet)
                guess[:3, 3] *= stretch
            out.append(odo.register(scan, guess=guess))
        return out

    for a, b in zip(poses(1.0), poses(1.5)):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_a_predicted_registration_keeps_kiss_icps_own_match_distance():
    """KISS-ICP's adaptive threshold sets the match distance that the registration covariance (what the graph
    weighs KISS-ICP's pose with, calibrated by `icp_cov_inflation`) is computed within. Predicting with the true
    motion must not shrink it: the threshold keeps measuring KISS-ICP's own constant-velocity error (learnt from
    the good predictions it shrank 3-10x on a tuning lap and the graph then trusted KISS-ICP up to 5x more in turns
    than its errors there deserve). A weaving drive whose speed changes every frame: constant velocity is off by
    4 degrees and 0.8 m a step, yet converges; on these clean scans the covariances agree either way."""
    from odometry.initial_pose import LidarOdometry

    n = 10
    scans, T_cl, steps = _turning_drive([2.0 * (-1) ** k for k in range(n)], [1.8 + 0.8 * (k % 2) for k in range(n)])

    def run(predicted: bool) -> tuple[float, np.ndarray]:
        odo, sigmas = LidarOdometry(T_cl), []
        for k, scan in enumerate(scans):
            odo.register(scan, guess=steps[k - 1] if k == 1 or (predicted and k) else None)
            sigmas.append(np.sqrt(np.trace(odo.covariance[:3, :3])))
        return odo.icp.adaptive_threshold.get_threshold(), np.array(sigmas[2:])

    own_threshold, own = run(predicted=False)
    predicted_threshold, predicted = run(predicted=True)
    assert own_threshold > 5.0  # the weave's constant-velocity misses grew it from its initial 2 m
    assert abs(predicted_threshold / own_threshold - 1) < 0.05
    np.testing.assert_allclose(predicted, own, rtol=0.15)


def test_a_guess_after_a_skipped_scan_is_not_used(monkeypatch):
    """The guess is the motion from the previous frame; after a scan KISS-ICP skipped (too few points) its last
    pose is an older frame's, so the guess would be one step short: KISS-ICP's own prediction is used then."""
    from odometry.initial_pose import LidarOdometry

    scans, T_cl, steps = _turning_drive([0.0] * 4)
    odo, predicted = LidarOdometry(T_cl), []
    real = LidarOdometry._register_predicted
    monkeypatch.setattr(
        LidarOdometry, "_register_predicted", lambda self, *a: predicted.append(self.frames) or real(self, *a)
    )
    odo.register(scans[0])
    odo.register(scans[1], guess=steps[0])
    assert predicted == [1]
    assert odo.register(scans[2][:10], guess=steps[1]) is None  # skipped
    odo.register(scans[3], guess=steps[2])
    assert predicted == [1]
    odo.register(scans[4], guess=steps[3])
    assert predicted == [1, 3]


def _failed_step_solves(cap: float) -> tuple[int, float]:
    """Linear solves of one smoother update whose Gauss-Newton step raises the error (a Jacobian 0.4x the
    residual's slope: the step overshoots 2.5x), and the estimate it leaves."""
    import gtsam

    from odometry.window_graph import lm_params

    key = gtsam.symbol("c", 0)

    def residual(this, values, H):
        if H is not None:
            H[0] = np.array([[0.4]])
        return values.atVector(key) - 1.0

    smoother = gtsam.BatchFixedLagSmoother(10.0, lm_params(cap))
    graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], residual))
    values.insert(key, np.array([0.0]))
    stamps.insert((key, 0.0))
    result = smoother.update(graph, values, stamps)
    return result.getIntermediateSteps(), float(smoother.calculateEstimate().atVector(key)[0])


def test_a_step_that_raises_the_error_ends_the_update_without_retries():
    """The default LM cap: a failed step is not solved again at a damping too small to change it (such
    retries make the graph's slowest frames; docs/decisions/0002-no-lm-retries.md); a cap of 1e-2 retries
    it 3 times, to the same end."""
    from odometry.window_graph import LM_LAMBDA_UPPER_BOUND

    assert LM_LAMBDA_UPPER_BOUND <= 1e-10
    solves, x = _failed_step_solves(LM_LAMBDA_UPPER_BOUND)
    assert solves == 1 and x == 0.0
    solves_old, x_old = _failed_step_solves(1e-2)
    assert solves_old == 4 and x_old == x


def _scaled_pixel_run(weighted: bool) -> float:
    """A camera moving 0.5 m per frame past 80 landmarks; half are seen with pixels 4 px off at random (keypoints
    of a coarse pyramid level, `pixel_scale` 4), half with 0.2 px. Returns the mean position error of the poses."""
    from leovr.config import RefineConfig
    from odometry.window_graph import FrameInput, Observation, WindowGraph

    rng = np.random.default_rng(5)
    pts = np.c_[rng.uniform(-6, 6, 80), rng.uniform(-3, 3, 80), rng.uniform(10, 30, 80)]
    coarse = np.arange(80) % 2 == 0
    g = WindowGraph(RefineConfig(window=3, graph={"depth_factors": False}), K, SHAPE, rng=np.random.default_rng(0))
    truth, done = [], []
    for i in range(6):
        T = make_T(t=[0.0, 0.0, 0.5 * i])
        truth.append(T)
        cam = (pts - T[:3, 3]) @ T[:3, :3]
        uv = (cam @ K.T)[:, :2] / cam[:, 2:] + rng.normal(0, 1, (80, 2)) * np.where(coarse, 4.0, 0.2)[:, None]
        scale = np.where(coarse, 4.0, 1.0) if weighted else np.ones(80)
        obs = [Observation(k, i, uv[k], None, float(scale[k])) for k in range(len(pts))]
        fi = FrameInput(
            i,
            T,
            np.full(SHAPE, np.log(20.0)),
            np.full(SHAPE, 0.2),
            obs,
            {k: pts[k] + rng.normal(0, 0.2, 3) for k in range(len(pts))} if i == 0 else {},
            None,
            None,
            None if i == 0 else make_T(t=[0.0, 0.0, 0.5]),
        )
        done += g.add_frame(fi)
    done += g.flush()
    est = [r.T_world_cam for r in sorted(done, key=lambda r: r.index)]
    return float(np.mean([np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(est, truth)]))


def test_reprojection_factors_weigh_each_pixel_by_its_pyramid_level():
    """ORB finds a keypoint on a pyramid level 1.2x coarser per level; its pixel is known that much less well,
    and the graph's reprojection factors weigh it so (ORB-SLAM's rule)."""
    from odometry.features import SCALE_FACTOR, detect

    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur((rng.random((240, 320)) * 255).astype(np.uint8), (0, 0), 1.5)
    feats = detect(np.dstack([image] * 3), 500)
    assert feats.octave is not None and feats.octave.max() >= 2
    idx = np.arange(len(feats))
    assert np.allclose(feats.pixel_scale(idx), SCALE_FACTOR**feats.octave)
    assert _scaled_pixel_run(weighted=True) < 0.7 * _scaled_pixel_run(weighted=False)


@pytest.mark.slow
@needs_shared
def test_orb_matches_are_those_of_opencvs_brute_force_matcher_on_a_real_drive():
    """`match` computes the mutual check only for the chosen features: on consecutive frames of both KITTI raw
    clips, at the front end's and the sweep's feature counts, it returns exactly the mutual ratio-test matches of
    OpenCV's BFMatcher (knnMatch both ways), in the same order."""
    from leovr.data import open_sequence
    from leovr.paths import kitti_raw_clips
    from odometry.features import detect, match

    def reference(a, b, ratio=0.8, max_distance=64):
        bf = cv2.BFMatcher(cv2.NORM_HAMMING)
        back = {m.queryIdx: m.trainIdx for m in bf.match(b.desc, a.desc)}
        pairs = [
            (m.queryIdx, m.trainIdx)
            for m, n in bf.knnMatch(a.desc, b.desc, k=2)
            if m.distance < ratio * n.distance and m.distance <= max_distance and back.get(m.trainIdx) == m.queryIdx
        ]
        return np.array(pairs, np.int64).reshape(-1, 2).T

    checked = 0
    for clip in kitti_raw_clips():
        seq = open_sequence(clip)
        for k in range(0, len(seq) - 1, 6):
            for n in (1000, 2000):
                a, b = detect(seq[k].image, n), detect(seq[k + 1].image, n)
                ia, ib = match(a, b)
                ra, rb = reference(a, b)
                assert len(ia) > 100
                assert np.array_equal(ia, ra) and np.array_equal(ib, rb), (clip.name, k, n)
                checked += 1
    assert checked >= 10


def test_a_window_still_indeterminate_when_rebuilt_drops_the_landmark_behind_its_camera():
    """A landmark placed a millimetre in front of the camera that projects it (the projection's Jacobians blow up
    there; on a rendered lap one sat behind two of its three cameras) keeps the window indeterminate even with
    its depth prior: the rebuilt window leaves it out, keeps the other landmark and the poses, and warns."""
    from odometry.window_recovery import anchor_landmarks

    def X(i):
        return gtsam.symbol("x", i)

    def L(k):
        return gtsam.symbol("l", k)

    def new():
        return gtsam.IncrementalFixedLagSmoother(10.0, gtsam.ISAM2Params())

    cal = gtsam.Cal3_S2(500, 500, 0, 320, 240)
    graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap()
    step = gtsam.Pose3(gtsam.Rot3(), [0, 0, 1.0])
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    graph.add(gtsam.BetweenFactorPose3(X(0), X(1), step, gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    for i, T in enumerate((gtsam.Pose3(), step)):
        values.insert(X(i), T)
        stamps.insert((X(i), float(i)))
    for k, P in enumerate(([1.0, 0.5, 10.0], [0.5, 0.0, 1.001])):
        values.insert(L(k), np.array(P))
        stamps.insert((L(k), 1.0))
        for i in (0, 1):
            uv = np.array([320.0 + 500 * P[0] / (P[2] - i), 240.0 + 500 * P[1] / (P[2] - i)]) + 1.0
            graph.add(
                gtsam.GenericProjectionFactorCal3_S2(uv, gtsam.noiseModel.Isotropic.Sigma(2, 1.0), X(i), L(k), cal)
            )
    smoother = new()
    with pytest.raises(RuntimeError, match="ndeterminate") as failure:
        smoother.update(graph, values, stamps)
    with pytest.warns(UserWarning, match="landmarks l1 left the window"):
        smoother = anchor_landmarks(smoother, new, True, np.zeros(3), 1, failure.value)
    est = smoother.calculateEstimate()
    assert not est.exists(L(1)) and est.exists(L(0))
    assert np.allclose(est.atPose3(X(1)).translation(), [0, 0, 1.0], atol=0.01)
