"""The sweep's motion for deskewing: read from the two images where the last step is wrong (a turn's
start), the last step kept where it is right, and the first two scans' own motion before any step."""

import numpy as np
import pytest

from leovr.config import SimulateConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T
from leovr.sim.simulate import simulate
from tests.conftest import KITTI_RAW_POSES, needs_posed_drive
from odometry.features import detect
from odometry.initial_pose import first_step
from odometry.sweep_motion import SweepMotion, images_motion, sweep_motion


def _deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


@pytest.fixture(scope="module")
def turning(tmp_path_factory) -> object:
    """A city loop at 80 km/h: it starts in a 90-degree turn, about 13 degrees of yaw a frame."""
    out = tmp_path_factory.mktemp("turn") / "seq"
    simulate(
        SimulateConfig(scenario="city_loop", lidar="vlp16", frames=4, seed=3001, speed_kmh=80.0), out, progress=False
    )
    return open_sequence(out)


def test_images_replace_a_last_step_that_missed_the_turn(turning):
    f1, f2 = turning[1], turning[2]
    truth = invert_T(f1.T_world_cam) @ f2.T_world_cam
    assert _deg(truth[:3, :3]) > 10.0  # the scene turns
    straight = np.eye(4)
    straight[:3, 3] = [0.0, 0.0, np.linalg.norm(truth[:3, 3])]  # the step before a turn: straight on
    seen = images_motion(detect(f1.image, 2000), detect(f2.image, 2000), f1.K)
    out = sweep_motion(seen, f1.K, straight)
    assert out is not straight
    assert _deg(invert_T(truth)[:3, :3] @ out[:3, :3]) < 1.5
    assert np.linalg.norm(out[:3, 3] - truth[:3, 3]) < 0.15
    # the right step is kept as it is
    assert sweep_motion(seen, f1.K, truth) is truth


def test_sweep_motion_reuses_the_next_images_features(turning, monkeypatch):
    calls = []
    import odometry.sweep_motion as sm

    real = sm.detect
    monkeypatch.setattr(sm, "detect", lambda img, n: calls.append(1) or real(img, n))
    motion = SweepMotion()
    for k in (1, 2):
        motion(k, turning[k].image, k + 1, turning[k + 1].image, turning[k].K)
    assert len(calls) == 3  # frames 1, 2 and 3, each once


def test_first_step_from_the_first_two_raw_scans(turning):
    f0, f1 = turning[0], turning[1]
    truth = invert_T(f0.T_world_cam) @ f1.T_world_cam
    T = first_step(f0.points, f1.points, f0.T_cam_lidar)
    assert T is not None
    assert abs(np.linalg.norm(T[:3, 3]) - np.linalg.norm(truth[:3, 3])) < 0.15 * np.linalg.norm(truth[:3, 3])
    assert first_step(f0.points[:10], f1.points, f0.T_cam_lidar) is None  # too few points: no motion


@pytest.mark.slow
def test_refine_predicts_kiss_icp_with_the_images_motion_only_where_it_overruled_the_last_step(tmp_path, monkeypatch):
    """With a spinning LiDAR KISS-ICP starts from the sweep's motion read from the images only at frames where
    that motion overruled the last step (a turn's start or end); elsewhere it keeps its own prediction, so its
    poses equal those of a run that never passes the images' motion (its own constant velocity) up to the first
    predicted frame and differ after it."""
    import json

    from leovr.config import RefineConfig
    from leovr.pipeline.refine import run_refine
    from odometry.initial_pose import LidarOdometry
    from odometry.frontend import FrontEnd

    seq_dir = tmp_path / "seq"  # a city loop at 80 km/h that starts in a 90-degree turn and leaves it
    simulate(
        SimulateConfig(scenario="city_loop", lidar="vlp16", frames=10, seed=3001, speed_kmh=80.0),
        seq_dir,
        progress=False,
    )
    seq = open_sequence(seq_dir)
    predicted: list[int] = []
    real = LidarOdometry._register_predicted
    monkeypatch.setattr(
        LidarOdometry, "_register_predicted", lambda self, *a: predicted.append(self.frames) or real(self, *a)
    )

    def icp_poses(name: str) -> dict[int, np.ndarray]:
        run_refine(seq, RefineConfig(input="full"), tmp_path / name, progress=False)
        state = json.loads((tmp_path / name / "progress.json").read_text())
        return {int(k): np.array(v).reshape(4, 4) for k, v in state["icp_poses"].items()}

    with monkeypatch.context() as m:  # the images' motion never reaches KISS-ICP
        process = FrontEnd.process
        m.setattr(FrontEnd, "process", lambda self, *a, icp_guess=None, **k: process(self, *a, **k))
        own = icp_poses("own")
    assert predicted == []
    images = icp_poses("images")
    assert 0 < len(predicted) < 9, predicted  # some frames, not every frame (9 registrations after the first)
    first = predicted[0]
    for k in range(first):
        np.testing.assert_allclose(images[k], own[k], atol=1e-9)
    assert max(np.abs(images[k] - own[k]).max() for k in range(first, len(seq))) > 1e-4


@pytest.mark.slow
@needs_posed_drive
def test_a_spinning_lidars_sweep_is_deskewed_over_kiss_icps_step_length(tmp_path, monkeypatch):
    """Real drive, VLP-16-like: the step each sweep is deskewed over (the generator stage's `motion`, KISS-ICP's
    last steps' mean length) has the true step's length to 4 % rms over 40 frames. The front end's initial pose is
    PnP's wherever it reprojects more matches, and its step length wobbles with the matched depth (7 % rms over the
    same frames); a sweep deskewed over that registers with the opposite error."""
    from leovr.config import RefineConfig
    from leovr.pipeline.refine import run_refine
    from leovr.pipeline.refine_prepare import PrepareStage

    seen: dict[int, np.ndarray | None] = {}
    prepare = PrepareStage.prepare

    def recording(self, i, motion, *a):
        seen.setdefault(i, motion)
        return prepare(self, i, motion, *a)

    monkeypatch.setattr(PrepareStage, "prepare", recording)
    seq = open_sequence(KITTI_RAW_POSES)
    run_refine(seq, RefineConfig(input="vlp16", end=40), tmp_path / "run", progress=False, score=False)
    truth = [seq.pose(i) for i in range(40)]
    ratios = [
        np.linalg.norm(m[:3, 3]) / np.linalg.norm((invert_T(truth[i - 2]) @ truth[i - 1])[:3, 3])
        for i, m in seen.items()
        if m is not None and i >= 3
    ]
    assert len(ratios) >= 30
    assert np.sqrt(np.mean((np.array(ratios) - 1) ** 2)) < 0.04, np.round(ratios, 3)
