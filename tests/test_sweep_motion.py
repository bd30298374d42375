"""The sweep's motion for deskewing: the rotation read from the two images (a turn's start, which the last step
misses), the direction of travel on the last step's arc (which the essential matrix trades for a yaw on a straight
real drive), and the first two scans' own motion before any step."""

from dataclasses import replace

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


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Degrees between two directions, either sign of the first (an essential matrix's has none)."""
    return float(np.degrees(np.arccos(np.clip(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.fixture(scope="module")
def turning(tmp_path_factory) -> object:
    """A city loop at 80 km/h: it starts in a 90-degree turn, about 11-13 degrees of yaw a frame, that ends between
    frames 7 and 8 (2 degrees)."""
    out = tmp_path_factory.mktemp("turn") / "seq"
    simulate(
        SimulateConfig(scenario="city_loop", lidar="vlp16", frames=9, seed=3300, speed_kmh=80.0), out, progress=False
    )
    return open_sequence(out)


def _sweep(seq, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame k's last step, its sweep's motion from the images along that step, and the true motion."""
    last = invert_T(seq[k - 1].T_world_cam) @ seq[k].T_world_cam
    truth = invert_T(seq[k].T_world_cam) @ seq[k + 1].T_world_cam
    seen = images_motion(detect(seq[k].image, 2000), detect(seq[k + 1].image, 2000), seq[k].K)
    return last, sweep_motion(seen, seq[k].K, last), truth


def test_images_replace_a_last_step_that_missed_the_turns_end(turning):
    last, out, truth = _sweep(turning, 7)
    assert _deg(last[:3, :3].T @ truth[:3, :3]) > 5.0  # the turn ends: the last step turns on
    assert _deg(out[:3, :3].T @ truth[:3, :3]) < 0.5
    assert np.linalg.norm(out[:3, 3] - truth[:3, 3]) < 0.5 * np.linalg.norm(last[:3, 3] - truth[:3, 3])
    # in the turn, on its arc: the direction of travel turns with the rotation
    last, out, truth = _sweep(turning, 5)
    assert _deg(truth[:3, :3]) > 10.0
    assert _deg(out[:3, :3].T @ truth[:3, :3]) < 0.2
    assert np.linalg.norm(out[:3, 3] - truth[:3, 3]) < 0.02
    # a cone keeps a right last step as it is (its sweep motion is not held on the arc)
    seen = images_motion(detect(turning[5].image, 2000), detect(turning[6].image, 2000), turning[5].K)
    assert sweep_motion(seen, turning[5].K, truth, along_arc=False) is truth
    # no motion read from the images: the last step as it is
    assert sweep_motion(replace(seen, motion=None), turning[5].K, last) is last


@needs_posed_drive
def test_the_direction_of_travel_follows_the_arc_where_the_essential_matrix_trades_it_for_a_yaw():
    """Real drive, frames 40-70 (straight, 11-14 m/s): the essential matrix of the ORB matches puts the direction of
    travel 10-50 degrees sideways at many frames, with a compensating yaw, and more matches agree with it than with
    the true motion. Given the true last step, the sweep's motion keeps the direction to 1 degree and the rotation
    to 0.25 degree of the true ones at every frame."""
    seq = open_sequence(KITTI_RAW_POSES)
    frames = range(39, 71)
    feats = {k: detect(seq[k].image, 2000) for k in frames}
    K = seq[frames[0]].K
    essential_off, direction_off, rotation_off = [], [], []
    for k in frames[1:-1]:
        last = invert_T(seq.pose(k - 1)) @ seq.pose(k)
        truth = invert_T(seq.pose(k)) @ seq.pose(k + 1)
        seen = images_motion(feats[k], feats[k + 1], K)
        out = sweep_motion(seen, K, last)
        essential_off.append(_angle(seen.motion[:3, 3], truth[:3, 3]))
        direction_off.append(_angle(out[:3, 3], truth[:3, 3]))
        rotation_off.append(_deg(out[:3, :3].T @ truth[:3, :3]))
        assert abs(np.linalg.norm(out[:3, 3]) - np.linalg.norm(last[:3, 3])) < 1e-9  # the last step's length
    assert sum(a > 10.0 for a in essential_off) >= 5, np.round(essential_off, 1)
    assert max(direction_off) < 1.0, np.round(direction_off, 2)
    assert max(rotation_off) < 0.25, np.round(rotation_off, 2)


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
@pytest.mark.parametrize("lidar", ["vlp16", "mid40"])
def test_refine_predicts_kiss_icp_with_each_sweeps_motion_read_from_the_images(tmp_path, monkeypatch, lidar):
    """With a spinning or a cone LiDAR KISS-ICP starts each registration after the first from the sweep's motion
    read from the images (a turn's start and end, which its own constant velocity misses) wherever that is not the
    last step again, and its poses differ from those of a run that never passes that motion."""
    import json

    from leovr.config import RefineConfig
    from leovr.pipeline.refine import run_refine
    from leovr.pipeline.refine_sweep import SweepDeskew
    from odometry.initial_pose import LidarOdometry
    from odometry.frontend import FrontEnd

    seq_dir = tmp_path / "seq"  # a city loop at 80 km/h that starts in a 90-degree turn and leaves it
    simulate(
        SimulateConfig(scenario="city_loop", lidar=lidar, frames=10, seed=3001, speed_kmh=80.0),
        seq_dir,
        progress=False,
    )
    seq = open_sequence(seq_dir)
    predicted: list[int] = []
    real = LidarOdometry._register_predicted
    monkeypatch.setattr(
        LidarOdometry, "_register_predicted", lambda self, *a: predicted.append(self.frames) or real(self, *a)
    )
    read: dict[int, bool] = {}  # frame -> whether its sweep's images gave a motion other than the last step
    motion = SweepDeskew.motion

    def recorded(self, i, *a, **k):
        out = motion(self, i, *a, **k)
        read[i] = self.motion_of.get(i) is not None
        return out

    monkeypatch.setattr(SweepDeskew, "motion", recorded)

    def icp_poses(name: str) -> dict[int, np.ndarray]:
        run_refine(seq, RefineConfig(input="full"), tmp_path / name, progress=False)
        state = json.loads((tmp_path / name / "progress.json").read_text())
        return {int(k): np.array(v).reshape(4, 4) for k, v in state["icp_poses"].items()}

    with monkeypatch.context() as m:  # the images' motion never reaches KISS-ICP
        process = FrontEnd.process
        m.setattr(FrontEnd, "process", lambda self, *a, icp_guess=None, **k: process(self, *a, **k))
        own = icp_poses("own")
    assert predicted == []
    read.clear()
    images = icp_poses("images")
    # each registration after the first where the sweep before it was read from the images: with a spinning LiDAR
    # every one (the arc's motion is never the last step itself); a cone's sweep keeps the last step unless the
    # images clearly disagree, and KISS-ICP its own constant velocity there
    assert predicted and predicted == [k for k in range(1, len(seq)) if read[k - 1]], (predicted, read)
    if lidar == "vlp16":
        assert predicted == list(range(1, len(seq)))
    np.testing.assert_allclose(images[0], own[0], atol=1e-9)
    assert max(np.abs(images[k] - own[k]).max() for k in range(1, len(seq))) > 1e-4


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


def test_a_sweep_is_judged_spinning_on_its_first_scan_with_returns_enough():
    """The arc is held for a spinning LiDAR only; a first scan with too few returns to tell leaves the judgement to
    a later one (the cone's sweep motion until then) rather than settling it as a cone for the whole run."""
    from types import SimpleNamespace

    from leovr.pipeline.refine_sweep import SweepDeskew

    rng = np.random.default_rng(0)
    az = rng.uniform(-np.pi, np.pi, 5000)
    ring = np.c_[20 * np.cos(az), 20 * np.sin(az), np.zeros_like(az)]  # returns all around the sensor
    scans = iter([None, ring[:10], ring])
    sweep = SweepDeskew.__new__(SweepDeskew)
    sweep._spinning = None
    sweep.setup = SimpleNamespace(sample=lambda frame, motion: SimpleNamespace(kept_points=next(scans)))
    assert not sweep.spinning(None)  # no scan
    assert not sweep.spinning(None)  # ten returns
    assert sweep.spinning(None)  # the whole ring
    assert sweep.spinning(None)  # judged: not read again (the iterator is spent)
