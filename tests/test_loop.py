"""Loop closure: vocabulary, detection rule, geometric validation, pose graph (end to end: `leovr bench loop`)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from leovr.errors import DataError
from leovr.geometry import make_T
from odometry.features import Features
from odometry.loop.detector import LoopDetector
from odometry.loop.pose_graph import optimise_pose_graph
from odometry.loop.validate import consistent_loops, validate_loop
from odometry.loop.vocabulary import Vocabulary

K = np.array([[200.0, 0, 160], [0, 200.0, 120], [0, 0, 1]])


def _clustered(rng, centers: np.ndarray, n: int, flips: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors near given 256-bit centres (a few bits flipped); returns packed descriptors, labels."""
    label = rng.integers(len(centers), size=n)
    bits = centers[label].copy()
    for r in range(n):
        bits[r, rng.choice(256, flips, replace=False)] ^= 1
    return np.packbits(bits, axis=1), label


def test_vocabulary_separates_clusters_and_round_trips(tmp_path):
    rng = np.random.default_rng(0)
    centers = rng.integers(0, 2, (9, 256)).astype(np.uint8)
    desc, label = _clustered(rng, centers, 900)
    voc = Vocabulary.train(desc, k=4, levels=2, docs=[desc[:300], desc[300:600], desc[600:]])
    words = voc.words_of(desc)
    # each cluster lands (almost) entirely in one word, and different clusters in different words
    main = [np.bincount(words[label == c], minlength=16).argmax() for c in range(9)]
    purity = np.mean([np.mean(words[label == c] == main[c]) for c in range(9)])
    assert purity > 0.95 and len(set(main)) >= 8
    voc.save(tmp_path / "v.npz")
    again = Vocabulary.load(tmp_path / "v.npz")
    assert np.array_equal(again.words_of(desc), words) and np.allclose(again.idf, voc.idf)
    (tmp_path / "bad.npz").write_bytes(b"nonsense")
    with pytest.raises(DataError, match="bad.npz"):
        Vocabulary.load(tmp_path / "bad.npz")


def test_detector_needs_a_consistent_revisit():
    rng = np.random.default_rng(1)
    bows = [(np.sort(rng.choice(10_000, 60, replace=False)), np.full(60, 1 / 60, np.float32)) for _ in range(60)]
    det = LoopDetector(min_gap=20)
    # consecutive frames share half their words (co-visibility sets the bar)
    for f in range(1, 60):
        bows[f] = (np.unique(np.r_[bows[f][0][:30], bows[f - 1][0][:30]]), None)
        bows[f] = (bows[f][0], np.full(len(bows[f][0]), 1 / len(bows[f][0]), np.float32))
    found = [det.add(f, bows[f]) for f in range(40)]
    assert all(x is None for x in found)  # no revisit yet
    found = [det.add(40 + k, bows[5 + k]) for k in range(8)]  # frames 40.. revisit 5..
    hits = [x for x in found if x is not None]
    assert found[:3] == [None, None, None]  # accepted only after more than three consistent frames
    assert hits and all(5 <= j <= 12 for j, _ in hits)
    assert all(5 <= j <= 12 for j, _ in hits)


def _two_views(rng, T_j_i: np.ndarray, z_min: float, n: int = 120):
    """n random points ahead of camera i (depth z_min-30 m) seen by both cameras, one shared descriptor
    each: frame i's and j's features and camera-frame points."""
    pts_i = np.c_[rng.uniform(-6, 6, n), rng.uniform(-2, 2, n), rng.uniform(z_min, 30, n)]
    pts_j = pts_i @ T_j_i[:3, :3].T + T_j_i[:3, 3]
    desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    fi = Features(((pts_i @ K.T)[:, :2] / pts_i[:, 2:]).astype(np.float32), desc)
    fj = Features(((pts_j @ K.T)[:, :2] / pts_j[:, 2:]).astype(np.float32), desc)
    return fi, pts_i, fj, pts_j


def test_validation_recovers_the_relative_pose_and_rejects_unrelated_frames():
    rng = np.random.default_rng(2)
    n = 120
    T_j_i = make_T(Rotation.from_rotvec([0, 0.1, 0]).as_matrix(), [0.5, 0, -2.0])
    fi, pts_i, fj, pts_j = _two_views(rng, T_j_i, 5.0, n)
    check = validate_loop(fi, pts_i, fj, pts_j, K)
    assert check.accepted and check.inliers == n and np.allclose(check.T_j_i, T_j_i, atol=1e-6)
    other = rng.integers(0, 256, (n, 32), dtype=np.uint8)
    bad = validate_loop(fi, pts_i, Features(fj.uv, other), pts_j, K)
    assert not bad.accepted


def test_validation_refuses_a_loop_whose_two_pnp_poses_disagree_by_more_than_20_cm():
    # frame i's depths s times too far: the forward PnP (frame j's points) stays exact, the reverse one
    # (frame i's points) puts camera j at s times its 6 m offset, so the two disagree by (s - 1) x 6 m
    T_j_i = make_T(Rotation.from_rotvec([0, 0.05, 0]).as_matrix(), [0.3, 0, -6.0])
    fi, pts_i, fj, pts_j = _two_views(np.random.default_rng(3), T_j_i, 10.0)
    near = validate_loop(fi, pts_i * 1.02, fj, pts_j, K)
    assert near.accepted and near.disagree_m == pytest.approx(0.12, abs=0.01)
    assert np.allclose(near.T_j_i, T_j_i, atol=1e-5)
    far = validate_loop(fi, pts_i * 1.04, fj, pts_j, K)
    assert not far.accepted and far.disagree_m == pytest.approx(0.24, abs=0.01)
    assert validate_loop(fi, pts_i * 1.04, fj, pts_j, K, max_disagree_m=0.5).accepted  # a looser limit accepts it


def test_pose_graph_pulls_a_drifted_loop_closed():
    # a square drive of 40 poses; odometry with a small yaw drift; the last pose revisits the first
    gt = [make_T(Rotation.from_euler("y", 90 * (k // 10), degrees=True).as_matrix()) for k in range(40)]
    pos = np.zeros(3)
    for k in range(40):
        gt[k][:3, 3] = pos
        pos = pos + gt[k][:3, :3] @ np.array([0, 0, 2.0])
    drift = make_T(Rotation.from_euler("y", 1.0, degrees=True).as_matrix())
    est = [gt[0]]
    for k in range(1, 40):
        est.append(est[-1] @ drift @ np.linalg.inv(gt[k - 1]) @ gt[k])
    est = np.stack(est)
    loop = (39, 0, np.linalg.inv(gt[0]) @ gt[39])
    fixed = optimise_pose_graph(est, [loop])
    err = lambda P: np.mean([np.linalg.norm(P[k][:3, 3] - gt[k][:3, 3]) for k in range(40)])  # noqa: E731
    assert err(fixed) < 0.5 * err(est)


def test_pose_graph_puts_a_loops_correction_on_the_step_the_window_was_least_sure_of():
    """A square lap of 40 poses, 2 m steps, exact but for a 3-degree heading error at one turn (step 20) that the
    window was unsure of (its sigmas there 20 times the others); pose 39 revisits pose 0. Weighted by the window's
    covariances the loop's correction goes mostly to that step (mean error 0.41 -> 0.04 m); with every step
    weighted alike it is spread over the lap and bends the sides (0.15 m)."""
    n = 40
    gt = [make_T(Rotation.from_euler("y", 90 * (k // 10), degrees=True).as_matrix()) for k in range(n)]
    pos = np.zeros(3)
    for k in range(n):
        gt[k][:3, 3] = pos
        pos = pos + gt[k][:3, :3] @ np.array([0, 0, 2.0])
    est = [gt[0]]
    for k in range(1, n):
        step = np.linalg.inv(gt[k - 1]) @ gt[k]
        if k == 20:
            step = step @ make_T(Rotation.from_euler("y", 3.0, degrees=True).as_matrix())
        est.append(est[-1] @ step)
    est = np.stack(est)
    loop = (39, 0, np.linalg.inv(gt[0]) @ gt[39])
    sure = np.diag(np.r_[np.full(3, 1e-3**2), np.full(3, 0.02**2)])
    covs = [None] + [sure * (400.0 if k == 20 else 1.0) for k in range(1, n)]
    err = lambda P: float(np.mean([np.linalg.norm(P[k][:3, 3] - gt[k][:3, 3]) for k in range(n)]))  # noqa: E731
    alike = optimise_pose_graph(est, [loop], [None] + [sure] * (n - 1))
    weighted = optimise_pose_graph(est, [loop], covs)
    assert err(est) > 0.4
    assert err(weighted) < 0.15 * err(est) and err(weighted) < 0.4 * err(alike)


def test_the_window_step_covariance_is_the_relative_poses_marginal():
    """A chain: a prior on pose 0, then steps of sigma 0.2 and 0.3 (with a turn): the covariance of each step
    into pose 1 and 2 is that step's own noise."""
    import gtsam

    from odometry.step_covariance import window_step_covariances

    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    step = gtsam.Pose3(gtsam.Rot3.Yaw(0.5), np.array([1.0, 0.2, 0.0]))
    v.insert(0, gtsam.Pose3())
    for k, sigma in ((1, 0.2), (2, 0.3)):
        g.add(gtsam.BetweenFactorPose3(k - 1, k, step, gtsam.noiseModel.Isotropic.Sigma(6, sigma)))
        v.insert(k, v.atPose3(k - 1).compose(step))
    poses = {k: v.atPose3(k).matrix() for k in range(3)}
    covs = window_step_covariances(g, v, {k: k for k in range(3)}, poses)
    assert covs.keys() == {1, 2}
    assert np.allclose(covs[1], 0.04 * np.eye(6), atol=1e-9) and np.allclose(covs[2], 0.09 * np.eye(6), atol=1e-9)


def test_consistent_loops_rejects_the_odd_one_out():
    """A run of loops measured from true poses agrees through the odometry; one measurement off by
    1.5 m is dropped, and so is a loop with no neighbour to confirm it."""
    rng = np.random.default_rng(3)
    poses = np.stack(
        [make_T(Rotation.from_rotvec([0, 0.02 * k, 0]).as_matrix(), [0.1 * k, 0, 1.0 * k]) for k in range(60)]
    )
    true = lambda i, j: np.linalg.solve(poses[j], poses[i])  # noqa: E731  camera i in camera j
    loops = [(i, i - 40, true(i, i - 40)) for i in (50, 51, 52, 53)]
    bad = true(54, 14)
    bad[:3, 3] += [1.5, 0, 0]
    loops.append((54, 14, bad))
    loops.append((59, 3, true(59, 3) @ make_T(Rotation.from_rotvec(rng.normal(0, 0.001, 3)).as_matrix(), [0, 0, 0])))
    assert consistent_loops(loops, poses) == [True, True, True, True, False, False]


def test_a_rendered_laps_true_loops_bring_it_closer_to_the_truth_where_the_window_was_least_sure():
    """Replayed from a run on the rendered quick lap of `leovr bench loop` (Mid-40, 120 frames, seed 3300;
    `tools/loop_lap_fixture.py`): the window's poses, its step covariances and the ten loops it accepted, all
    true. Weighed by the window's covariances the loops take the trajectory from 1.07 m to 0.75 m ATE; every step
    weighed alike only to 0.91 m."""
    from pathlib import Path

    from leovr.eval.trajectory import trajectory_metrics

    d = np.load(Path(__file__).parent / "data" / "loop_lap_mid40.npz")
    poses, truth = d["poses"], d["truth"]
    loops = [(int(i), int(j), T) for (i, j), T in zip(d["loop_pairs"], d["loop_T"])]
    for i, j, T in loops:  # all true: each within 1 m of the true relative pose
        assert np.linalg.norm((np.linalg.inv(np.linalg.inv(truth[j]) @ truth[i]) @ T)[:3, 3]) < 1.0
    step_cov = [None if np.isnan(c).any() else c for c in d["step_cov"]]
    ate = lambda P: trajectory_metrics(P, truth)["ate_m"]  # noqa: E731
    weighted = ate(optimise_pose_graph(poses, loops, step_cov))
    alike = ate(optimise_pose_graph(poses, loops))
    assert weighted < 0.75 * ate(poses) and weighted < 0.9 * alike
