"""Camera-only poses: the textbook VO baseline (`mono_vo`), the epipolar front end with a metric step
length (`mono_motion`), and `refine --input none` / `poses --compare` end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from leovr.cli import app
from leovr.config import RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.paths import kitti_odometry_dir, kitti_raw_dir
from leovr.pipeline.refine import run_refine
from leovr.sim.simulate import simulate
from odometry.mono_motion import epipolar_agrees, parallax_agrees, sampson_px
from odometry.mono_motion import MonoMotion
from odometry.mono_vo import gray, mono_vo_poses, relative_motion, track
from tests.conftest import killed_after_saves, needs_shared


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    seq_dir = tmp_path_factory.mktemp("mono") / "seq"
    simulate(SimulateConfig(scenario="city_loop", lidar="mid40", frames=8, seed=3001), seq_dir, progress=False)
    seq = open_sequence(seq_dir)
    return seq_dir, [seq[i] for i in range(len(seq))]


def _truth(frames) -> np.ndarray:
    return np.stack([invert_T(frames[0].T_world_cam) @ f.T_world_cam for f in frames])


def test_the_camera_only_profile_puts_its_graph_settings_over_refine_graph():
    """Without LiDAR the graph runs with `refine.graph` and, in place of the keys it names,
    `refine.camera_only.graph` (by default a loose landmark prior and depth-consistency sigma); the front end
    with `refine.camera_only.n_features` ORB features."""
    from leovr.config import CameraOnlyGraphConfig, GraphConfig
    from leovr.pipeline.refine_input import camera_only_config

    assert set(CameraOnlyGraphConfig.model_fields) <= set(GraphConfig.model_fields)
    cfg = RefineConfig(
        graph={"pixel_sigma": 2.0, "landmark_prior_rel": 0.4}, camera_only={"graph": {"consistency_sigma_log": 0.5}}
    )
    graph = camera_only_config(cfg).graph
    assert (graph.pixel_sigma, graph.landmark_prior_rel, graph.consistency_sigma_log) == (2.0, 10.0, 0.5)
    assert graph.model_copy(update={"landmark_prior_rel": 0.4, "consistency_sigma_log": 0.05}) == cfg.graph
    assert cfg.graph.landmark_prior_rel == 0.4  # the LiDAR runs' settings are left as they are
    # and the front end its own ORB feature count (the graph's landmarks)
    assert camera_only_config(cfg).frontend.n_features == cfg.camera_only.n_features == 500
    assert cfg.frontend.n_features == 1000


def test_epipolar_motion_points_the_way_the_camera_moved(drive):
    _, frames = drive
    for a, b in zip(frames[:-1], frames[1:]):
        T, inl = relative_motion(*track(gray(a.image), gray(b.image)), a.K)
        true = invert_T(a.T_world_cam) @ b.T_world_cam  # pose of b in a
        cos = T[:3, 3] @ true[:3, 3] / np.linalg.norm(true[:3, 3])
        assert cos > np.cos(np.radians(15)), f"direction {T[:3, 3]} vs {true[:3, 3]}"
        dR = T[:3, :3].T @ true[:3, :3]
        assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 1.0
        assert inl.sum() > 50


def test_textbook_vo_follows_the_drive_up_to_scale(drive):
    _, frames = drive
    est = mono_vo_poses((f.image for f in frames), frames[0].K)
    t = trajectory_metrics(est, _truth(frames), "sim3")
    path = np.linalg.norm(np.diff(_truth(frames)[:, :3, 3], axis=0), axis=1).sum()
    assert t["ate_m"] < 0.05 * path and 0.3 < t["scale"] < 3  # unit steps, the drive's own speed after alignment


def test_step_length_is_metric_when_the_depth_is(drive):
    """With the true depth as the 'generator', the step length is the true one: the depth fixes scale."""
    _, frames = drive
    mm = MonoMotion(frames[0].K)
    truth = _truth(frames)
    sources = []
    for k, f in enumerate(frames):
        step = mm.step(f.image, f.depth, np.log(0.05 * np.maximum(f.depth, 1e-3)))
        if k == 0:
            assert step is None
            continue
        true_len = np.linalg.norm((invert_T(truth[k - 1]) @ truth[k])[:3, 3])
        sources.append(step.scale_source)
        assert np.linalg.norm(step.T_rel[:3, 3]) == pytest.approx(true_len, rel=0.1)
    assert sum(s.startswith("depth") for s in sources) >= len(sources) - 2  # a rare bad draw keeps the last motion


def test_the_road_gives_the_scale_where_the_depth_is_off(drive):
    """A generator whose depth is half the truth: without the camera height the steps are half as long;
    with it the road plane makes them metric and measures the depth's bias (the factor that corrects it)."""
    _, frames = drive
    truth = _truth(frames)
    true_len = np.array([np.linalg.norm((invert_T(truth[k - 1]) @ truth[k])[:3, 3]) for k in range(1, len(frames))])
    lengths = {}
    for h in (None, 1.65):
        mm = MonoMotion(frames[0].K, camera_height=h)
        steps = [mm.step(f.image, 0.5 * f.depth, np.log(0.05 * np.maximum(f.depth, 1e-3))) for f in frames][1:]
        lengths[h] = np.array([np.linalg.norm(s.T_rel[:3, 3]) for s in steps])
        if h:
            assert sum(s.scale_source.startswith("ground") for s in steps) >= len(steps) - 1
            assert mm.depth_scale == pytest.approx(2.0, rel=0.2)  # a running estimate over 7 noisy frames
    assert np.median(lengths[None] / true_len) == pytest.approx(0.5, rel=0.15)
    assert np.median(lengths[1.65] / true_len) == pytest.approx(1.0, abs=0.05)
    assert np.abs(lengths[1.65] / true_len - 1).max() < 0.15


def test_a_vehicle_driving_along_fails_the_parallax_test():
    """Forward motion of 1 m: a static point 10 m ahead shows the parallax its depth predicts; a car ahead
    at the camera's speed passes the epipolar test (no parallax at all lies on every epipolar line) but
    not this one; an oncoming car shows far more; a far point (under 3 px predicted) is not judged."""
    K = np.array([[720.0, 0, 620], [0, 720.0, 187], [0, 0, 1]])
    T = np.eye(4)
    T[2, 3] = 1.0
    X0 = np.array([[2.0, 1.0, 10.0], [1.0, 0.5, 10.0], [-2.0, 0.5, 10.0], [1.0, 0.0, 300.0]])

    def px(X):
        return (X @ K.T)[:, :2] / X[:, 2:3]

    uv0 = px(X0)
    moved = X0 - [0, 0, 1.0]  # the static scene seen from the new camera
    uv1 = px(moved)
    uv1[1] = uv0[1]  # driving along: the same pixel
    uv1[2] = px(X0[2:3] - [0, 0, 3.0])[0]  # oncoming at twice the speed
    assert (sampson_px(T, uv0, uv1, K) < 0.01).all()  # all of them pass the epipolar test
    assert parallax_agrees(T, X0, uv0, uv1, K).tolist() == [True, False, False, True]


def test_with_the_road_triangulated_landmarks_get_the_loose_prior(drive):
    """Where the road gave the step, landmarks whose rays part by at least
    `MONO_GROUND_TRIANGULATION_MIN_DEG` are placed by the metric motion and get the loose depth prior;
    without a camera height (scale from the generator's depth) every landmark keeps the default prior."""
    from odometry.frontend import MONO_TRIANGULATED_PRIOR_REL, FrontEnd
    from odometry.window_graph import WindowGraph

    _, frames = drive
    K, shape = frames[0].K, frames[0].shape
    cfg = RefineConfig(input="none")
    flagged = {}
    for h in (None, 1.65):
        front = FrontEnd(cfg, K, shape, np.eye(4), use_lidar=False, camera_height=h)
        graph = WindowGraph(cfg, K, shape, rng=np.random.default_rng(0))
        n_new, n_loose = 0, 0
        for i, f in enumerate(frames[:4]):
            depth = 0.7 * np.where(f.depth > 0, f.depth, 100.0)  # a generator has depth everywhere (sky: far)
            fi = front.process(i, f.image, depth, np.log(0.1 * depth), None, None, graph)
            assert set(fi.landmark_prior_rel) <= set(fi.new_landmarks)
            assert all(r == MONO_TRIANGULATED_PRIOR_REL for r in fi.landmark_prior_rel.values())
            n_new, n_loose = n_new + len(fi.new_landmarks), n_loose + len(fi.landmark_prior_rel)
            graph.add_frame(fi)
        flagged[h] = (n_loose, n_new)
    assert flagged[None][0] == 0 and flagged[None][1] > 100
    assert 0.1 * flagged[1.65][1] < flagged[1.65][0] < flagged[1.65][1]


def test_a_pnp_pose_that_breaks_the_epipolar_geometry_is_refused(drive):
    _, frames = drive
    a, b = frames[2], frames[3]
    p0, p1 = track(gray(a.image), gray(b.image))
    true = invert_T(a.T_world_cam) @ b.T_world_cam
    assert np.median(sampson_px(true, p0, p1, a.K)) < 1.0
    assert epipolar_agrees(true, p0, p1, a.K)
    wrong = true.copy()
    wrong[:3, 3] = np.linalg.norm(true[:3, 3]) * np.array([0.0, 1.0, 0.0])  # downwards instead of forward
    assert not epipolar_agrees(wrong, p0, p1, a.K)


def test_camera_only_refine_holds_the_scan_out_and_scores_the_textbook_beside(drive, tmp_path):
    seq_dir, frames = drive
    out = tmp_path / "o"
    m = run_refine(open_sequence(seq_dir), RefineConfig(input="none", compare=True), out, progress=False)
    assert "camera only" in m["mode"] and m["input"] == "none"
    sources = json.loads((out / "timing.json").read_text())["initial_pose_sources"]
    epipolar = sum(v for k, v in sources.items() if k.startswith("epipolar"))
    # PnP only where it passed the epipolar test, constant velocity only where the essential matrix failed
    assert epipolar >= len(frames) - 3 and sum(sources.values()) == len(frames) and sources["first"] == 1
    # the simulator records the camera's height: the road plane gives the scale
    assert sources.keys() <= {
        "first",
        "pnp",
        "constant_velocity",
        "epipolar (ground)",
        "epipolar (ground+tracks)",
        "epipolar (depth)",
        "epipolar (depth+tracks)",
    }
    assert sum(v for k, v in sources.items() if "ground" in k) >= len(frames) - 3
    assert json.loads((out / "run.json").read_text())["camera_height_m"] == pytest.approx(1.65)
    traj = m["trajectory"]
    assert {"leovr", "mono_vo"} <= traj.keys() and "kiss_icp" not in traj
    assert traj["leovr"]["align"] == traj["mono_vo"]["align"] == "sim3"
    print(traj)
    assert traj["leovr"]["ate_m"] < 1.0 and 0.8 < traj["leovr"]["scale"] < 1.25
    assert len((out / "poses_mono_vo_kitti.txt").read_text().splitlines()) == len(frames)
    assert m["depth"]["generator"]["n"] > 0 and "nearest" not in m["depth"]  # no LiDAR input to fill


@pytest.mark.slow
@needs_shared
def test_poses_compare_on_the_real_clip_without_lidar(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "poses",
            str(kitti_odometry_dir()),
            "--out",
            str(tmp_path / "p"),
            "--compare",
            "--no-loop-closure",
            "--config",
            str(_short_config(tmp_path, 10)),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "mono_vo" in res.output and "scale" in res.output
    m = json.loads((tmp_path / "p" / "metrics.json").read_text())
    assert m["trajectory"]["mono_vo"]["frames"] == m["trajectory"]["leovr"]["frames"] == 10
    assert "camera only" in m["mode"]


def _short_config(tmp_path, end: int):
    p = tmp_path / "short.yaml"
    p.write_text(f"refine:\n  end: {end}\n")
    return p


@pytest.mark.slow
@needs_shared
def test_camera_only_poses_on_the_real_raw_clip_stay_metric(tmp_path):
    """Without LiDAR the generator's errors on real frames grow with distance; as tight landmark priors and
    depth-consistency factors (the LiDAR settings) that depth pulled the road-scaled motion to a third of
    its length (Sim(3) scale 2.6 against KISS-ICP on the clip's full scan). The camera-only settings keep
    the poses metric."""
    from odometry.initial_pose import LidarOdometry

    seq, n = open_sequence(kitti_raw_dir()), 16
    icp = LidarOdometry(seq[0].T_cam_lidar)
    ref = np.stack([icp.register(seq[i].points) for i in range(n)])  # the scan is held out of the runs below
    scales = {}
    lidar_graph = {"landmark_prior_rel": 0.3, "consistency_sigma_log": 0.05}  # refine.graph's defaults
    for name, camera_only in (("shipped", {}), ("lidar_settings", {"graph": lidar_graph})):
        run_refine(
            seq,
            RefineConfig(input="none", end=n, camera_only=camera_only),
            tmp_path / name,
            progress=False,
            score=False,
        )
        est = read_kitti_poses(tmp_path / name / "poses_kitti.txt")
        scales[name] = trajectory_metrics(est, ref, "sim3")["scale"]
    print(scales)
    assert 0.8 < scales["shipped"] < 1.25
    assert scales["lidar_settings"] > 1.5


def test_an_indeterminate_window_is_anchored_and_the_run_goes_on(drive, tmp_path, monkeypatch):
    """gtsam may find a camera-only window (loose landmark priors) indeterminate after it took the frame's
    factors in (seen on a development drive with conditioned leaving observations): every landmark then
    gets a depth prior, the update runs again, and the run finishes with every pose, with a warning."""
    import odometry.window_graph as wg

    class FailsOnce:
        def __init__(self, real):
            self.real, self.calls = real, 0

        def update(self, *args):
            self.real.update(*args)
            self.calls += 1
            if self.calls == 5:
                raise RuntimeError("\nIndeterminate linear system detected while working near variable ...")

        def __getattr__(self, name):
            return getattr(self.real, name)

    made = []

    class Graph(wg.WindowGraph):
        def __post_init__(self) -> None:
            super().__post_init__()
            self.smoother = FailsOnce(self.smoother)
            made.append(self)

    monkeypatch.setattr(wg, "WindowGraph", Graph)
    seq_dir, frames = drive
    with pytest.warns(UserWarning, match="indeterminate"):
        m = run_refine(open_sequence(seq_dir), RefineConfig(input="none"), tmp_path / "o", progress=False)
    assert made and made[0].smoother.calls > 5
    assert len((tmp_path / "o" / "poses_kitti.txt").read_text().splitlines()) == len(frames)
    assert m["trajectory"]["leovr"]["ate_m"] < 1.0 and 0.8 < m["trajectory"]["leovr"]["scale"] < 1.25


def test_a_reversed_epipolar_motion_is_turned_back_to_the_heading():
    """Static points seen from a camera driving forward; the essential matrix's motion with its sign flipped
    (what a cheirality vote carried by movers gives) is turned back, with the points in front as inliers."""
    rng = np.random.default_rng(0)
    K = np.array([[700.0, 0, 620], [0, 700.0, 190], [0, 0, 1]])
    X = np.c_[rng.uniform(-15, 15, 300), rng.uniform(-3, 1.6, 300), rng.uniform(8, 60, 300)]
    T = np.eye(4)
    T[2, 3] = 1.0  # the second camera 1 m ahead of the first
    uv0 = X @ K.T
    uv1 = (X - T[:3, 3]) @ K.T
    p0, p1 = uv0[:, :2] / uv0[:, 2:], uv1[:, :2] / uv1[:, 2:]
    mm = MonoMotion(K)
    mm.heading = np.array([0.0, 0.0, 1.0])
    wrong = T.copy()
    wrong[2, 3] = -1.0
    motion, inl = mm._keep_heading(wrong, p0, p1, np.zeros(len(p0), bool))
    assert motion[2, 3] == pytest.approx(1.0) and inl.all()
    # a motion no match fits stays as it was
    same, kept = mm._keep_heading(wrong, p0, p1[::-1], np.zeros(len(p0), bool))
    assert same[2, 3] == pytest.approx(-1.0) and not kept.any()
    # a real reversal (the scene behind the matches supports it) stays a reversal
    back = T.copy()
    back[2, 3] = -1.0
    uvb = (X - back[:3, 3]) @ K.T
    motion, _ = mm._keep_heading(back, p0, uvb[:, :2] / uvb[:, 2:], np.ones(len(p0), bool))
    assert motion[2, 3] == pytest.approx(-1.0)


@pytest.mark.slow
@needs_shared
def test_traffic_ahead_does_not_turn_the_camera_only_motion_backwards():
    """KITTI raw clip, camera only: trucks drive off ahead while the car creeps forward (KISS-ICP on the full
    scan: every step forward); the essential matrix's cheirality vote, carried by the trucks, said backwards for
    every step from frame 31 on. Every step goes forward and the track is metric. The shared clip now ends at
    frame 23, before the trucks leave: it checks the creeping steps that lead up to them."""
    from leovr.pipeline.completion import EvalSample, generator_method
    from leovr.pipeline.refine_input import completion_config, road_height
    from odometry.initial_pose import LidarOdometry

    seq = open_sequence(kitti_raw_dir())
    n = min(40, len(seq))
    cfg = RefineConfig(input="none")
    gen = generator_method(completion_config(cfg))
    mm = MonoMotion(seq[0].K, camera_height=road_height(seq, cfg))
    icp = LidarOdometry(seq[0].T_cam_lidar)
    poses, ref = [np.eye(4)], []
    for i in range(n):
        f = seq[i]
        ref.append(icp.register(f.points))
        step = mm.step(f.image, *gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None)))
        if step is not None:
            assert step.T_rel[2, 3] >= 0, f"frame {i}: {step.T_rel[:3, 3]} ({step.scale_source})"
            poses.append(poses[-1] @ step.T_rel)
    traj = trajectory_metrics(np.stack(poses), np.stack(ref), "sim3")
    assert traj["ate_m"] < 0.2 and 0.8 < traj["scale"] < 1.25


@pytest.mark.slow
def test_a_resumed_camera_only_run_gives_the_poses_of_an_uninterrupted_one(drive, tmp_path):
    """The step-length filter carries state from frame to frame; a run killed after 4 frames and resumed
    replays the finished frames through the front end, so the written poses are those of an uninterrupted run."""
    import warnings

    seq_dir, frames = drive
    seq, cfg = open_sequence(seq_dir), RefineConfig(input="none", loop={"enabled": False})
    run_refine(seq, cfg, tmp_path / "whole", progress=False, score=False)
    with killed_after_saves(4):
        run_refine(seq, cfg, tmp_path / "cut", progress=False, score=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the replay matches the poses written before the interruption
        run_refine(seq, cfg, tmp_path / "cut", resume=True, progress=False, score=False)
    a, b = (read_kitti_poses(tmp_path / d / "poses_kitti.txt") for d in ("whole", "cut"))
    assert np.abs(a - b).max() < 1e-5 and len(a) == len(frames)


@needs_shared
def test_the_pose_recovered_from_an_essential_matrix_is_opencvs_on_every_pair_of_a_real_drive():
    """`recover_pose` picks the pose on a sample of the inliers and tests only that pose on the rest: on every
    consecutive pair of the real KITTI raw clip (its last frames barely move, where the sample cannot tell the four
    poses apart) it gives OpenCV's recoverPose's count, rotation, translation and mask exactly."""
    import cv2

    from odometry.mono_vo import recover_pose

    seq = open_sequence(kitti_raw_dir())
    K = seq[0].K
    images = [gray(seq[i].image) for i in range(len(seq))]
    for a in range(len(seq) - 1):
        p0, p1 = track(images[a], images[a + 1])
        E, mask = cv2.findEssentialMat(p1, p0, K, method=cv2.USAC_ACCURATE, prob=0.999, threshold=1.0)
        n, R, t, m = cv2.recoverPose(E[:3], p1, p0, K, mask=mask.copy())
        n2, R2, t2, m2 = recover_pose(E[:3], p1, p0, K, mask.ravel() > 0)
        assert n == n2 and np.array_equal(R, R2) and np.array_equal(t, t2), a
        np.testing.assert_array_equal(m.ravel() > 0, m2)
