"""Self-supervised training: warping, losses, flow mask, graph targets, the trainer without ground
truth (CLI, Rerun log, resume) and DistributedDataParallel over two processes."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from leovr.config import SelfSupConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T
from leovr.sim.simulate import simulate
from selfsup.blind import BlindSequence
from selfsup.flow_mask import epipolar_distance, fundamental, motion_flow_mask
from selfsup.losses import (
    feature_point_loss,
    photometric_error,
    refined_depth_loss,
    second_order_smoothness,
    sparse_depth_loss,
)
from selfsup.supervision import TrainFrame, landmark_depth, refined_agrees
from selfsup.warp import warp_image

REPO = Path(__file__).resolve().parents[1]
TINY = {
    "channels": [8, 8, 16, 16, 16],
    "blocks": [1, 1, 1, 1],
    "train_focal_px": 130.0,
    "loop_closure": False,
    "batch_size": 2,
}


def _K(f=100.0, cx=31.5, cy=23.5) -> torch.Tensor:
    return torch.tensor([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])


def test_warp_reproduces_a_shifted_view():
    """A fronto-parallel plane at 10 m seen by a camera 0.5 m to the right moves 5 px left (f = 100)."""
    rng = np.random.default_rng(0)
    h, w, shift = 48, 64, 5
    base = torch.from_numpy(rng.random((1, 3, h, w + shift))).float()
    img_i = base[..., :w]
    img_j = base[..., shift:]  # pixel u in i is pixel u - 5 in j
    T = torch.eye(4)[None]
    T[0, 0, 3] = -0.5  # camera-i point -> camera j (camera j sits 0.5 m to the right)
    depth = torch.full((1, 1, h, w), 10.0, requires_grad=True)
    warped, valid = warp_image(img_j, depth, T, _K()[None])
    assert valid[..., :shift].logical_not().all() and valid[..., shift:].all()
    assert torch.allclose(warped[..., shift:], img_i[..., shift:], atol=1e-5)
    # the photometric error is differentiable in depth
    photometric_error(img_i, warped)[valid].mean().backward()
    assert depth.grad is not None and depth.grad.abs().sum() > 0


def test_photometric_error_and_depth_terms():
    rng = np.random.default_rng(1)
    a = torch.from_numpy(rng.random((2, 3, 20, 30))).float()
    assert photometric_error(a, a).abs().max() < 1e-6
    noisy = (a + 0.2 * torch.from_numpy(rng.standard_normal(a.shape)).float()).clamp(0, 1)
    assert photometric_error(a, noisy).mean() > 0.05
    depth = torch.full((2, 1, 20, 30), 10.0)
    fd = torch.zeros_like(depth)
    fd[0, 0, 5, 5], fd[1, 0, 7, 9] = 12.0, 9.0
    assert feature_point_loss(depth, fd, "l2").item() == pytest.approx((4 + 1) / 2)
    assert feature_point_loss(depth, fd).item() == pytest.approx((np.log(12 / 10) + np.log(10 / 9)) / 2)
    refined = torch.full_like(depth, 11.0)
    assert refined_depth_loss(depth, refined, torch.tensor([True, False]), "l2").item() == pytest.approx(1.0)
    assert refined_depth_loss(depth, refined, torch.tensor([True, False])).item() == pytest.approx(np.log(1.1))
    assert refined_depth_loss(depth, refined, torch.tensor([False, False])).item() == 0.0
    # log_l1 is relative: 1 m off at 5 m costs as much as 10 m off at 50 m; l2 weighs the far one 100x
    near, far = torch.tensor([[[[5.0]]]]), torch.tensor([[[[50.0]]]])
    assert feature_point_loss(near * 1.2, near).item() == pytest.approx(feature_point_loss(far * 1.2, far).item())
    assert feature_point_loss(far * 1.2, far, "l2").item() == pytest.approx(
        100 * feature_point_loss(near * 1.2, near, "l2").item()
    )
    # a plane in inverse depth is perfectly smooth (second order); a step is not
    ramp = 1.0 / torch.linspace(0.05, 0.2, 30).expand(2, 1, 20, 30)
    step = depth.clone()
    step[..., 15:] = 20.0
    flat = torch.zeros_like(a)
    assert second_order_smoothness(ramp, flat).item() < 1e-5 < second_order_smoothness(step, flat).item()


def test_sparse_depth_term_pulls_only_the_returns_towards_the_lidar():
    depth = torch.full((1, 1, 8, 8), 10.0, requires_grad=True)
    sparse = torch.zeros(1, 1, 8, 8)
    sparse[0, 0, 2, 3], sparse[0, 0, 6, 1] = 20.0, 5.0
    loss = sparse_depth_loss(depth, sparse)
    assert loss.item() == pytest.approx(np.log(2.0))
    loss.backward()
    g = depth.grad[0, 0]
    assert g[2, 3] < 0 < g[6, 1]  # a step against the gradient moves each return's depth towards its LiDAR depth
    g[2, 3] = g[6, 1] = 0.0
    assert g.abs().max() == 0.0  # and no other pixel


def test_fundamental_matrix_and_epipolar_distance():
    rng = np.random.default_rng(2)
    K = _K().double().numpy()
    R, _ = np.linalg.qr(rng.standard_normal((3, 3)) * 0.05 + np.eye(3))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R * np.sign(np.linalg.det(R)), [0.3, -0.1, 1.0]
    P = rng.uniform([-5, -3, 8], [5, 3, 20], (50, 3))
    pi = P @ K.T
    Q = P @ T[:3, :3].T + T[:3, 3]
    pj = Q @ K.T
    pi, pj = pi / pi[:, 2:], pj / pj[:, 2:]
    F = fundamental(T, K)
    assert np.abs(np.einsum("ni,ij,nj->n", pj, F, pi)).max() < 1e-8
    # exact correspondences lie on their epipolar lines; a 2 px step across the line is 2 px off
    line = pi @ F.T
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    d_exact = np.abs(np.sum(pj * line, 1)) / np.linalg.norm(line[:, :2], axis=1)
    moved = pj.copy()
    moved[:, :2] += 2.0 * normal
    d_moved = np.abs(np.sum(moved * line, 1)) / np.linalg.norm(line[:, :2], axis=1)
    assert d_exact.max() < 1e-6 and np.allclose(d_moved, 2.0)
    # the dense version: a flow field that moves every pixel to its true match under a pure x translation
    Tx = np.eye(4)
    Tx[0, 3] = -0.5
    flow = np.zeros((48, 64, 2))
    flow[..., 0] = -5.0  # a plane at 10 m, f = 100: 5 px left, along the horizontal epipolar lines
    assert epipolar_distance(flow, fundamental(Tx, K)).max() < 1e-9
    flow[..., 1] = 1.5  # 1.5 px off the lines
    assert np.allclose(epipolar_distance(flow, fundamental(Tx, K)), 1.5)


@pytest.fixture(scope="module")
def dynamic_seq(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("selfsup") / "dyn"
    simulate(SimulateConfig(scenario="dynamic", lidar="mid40", frames=6, seed=1002), out, progress=False)
    return out


def test_flow_mask_drops_moving_objects(dynamic_seq):
    """On rendered frames with known moving-object masks, the epipolar test keeps most static pixels
    and drops a clearly larger share of moving ones (the ground truth is only read here, by the test).
    Objects moving along the epipolar lines (straight towards or away from the camera) pass the test by
    construction, so the moving share is not zero."""
    seq = open_sequence(dynamic_seq)
    kept_static, kept_moving = [], []
    for i in range(len(seq) - 1):
        a, b = seq[i], seq[i + 1]
        mask = motion_flow_mask(a.image, b.image, invert_T(b.T_world_cam) @ a.T_world_cam, a.K, 1.0)
        kept_static.append(mask[~a.moving_mask])
        kept_moving.append(mask[a.moving_mask])
    static, moving = np.concatenate(kept_static).mean(), np.concatenate(kept_moving).mean()
    assert np.concatenate(kept_moving).size > 0.01 * len(seq) * a.moving_mask.size
    assert static > 0.7 and moving < 0.75 * static


def test_landmark_depth_and_refined_agreement():
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]])
    f = TrainFrame(5, np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.float32), K)
    T = np.eye(4)
    T[:3, 3] = [1.0, 0, 0]  # camera 1 m along world x
    world = np.array([[1.0, 0, 10.0], [1.0, 0, 20.0], [1.5, 0.5, 5.0], [1.0, 0, -3.0]])
    d = landmark_depth(f, T, world, np.array([5, 6, 30, 5]), near_frames=4)
    assert d[24, 32] == pytest.approx(10.0)  # nearest of two on one pixel; the third was seen too long ago
    assert (d > 0).sum() == 1  # behind the camera: dropped
    fd = np.zeros((48, 64), np.float32)
    fd[::4, ::4] = 10.0
    assert refined_agrees(np.full_like(fd, 10.3), fd, 0.05)
    assert not refined_agrees(np.full_like(fd, 12.0), fd, 0.05)


def _no_truth_copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    for name in ("depth", "masks", "poses_tum.txt"):
        p = dst / name
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    return dst


@pytest.mark.slow
def test_selfsup_cli_without_ground_truth_rerun_and_resume(dynamic_seq, tmp_path):
    """`leovr train --mode selfsup` on a sequence whose ground truth files were deleted: trains, logs the
    flow mask / warped image / photometric error to Rerun, writes a loadable generator, resumes."""
    from rerun.chunk import RrdReader

    from leovr.config import CompleteConfig
    from leovr.depth.inference import load_generator, predict_at_focal
    from leovr.depth.runtime import for_inference
    from leovr.pipeline.completion import prepare_sample

    seq = _no_truth_copy(dynamic_seq, tmp_path / "blind")
    info = open_sequence(seq).info()
    assert not info.has_depth and not info.has_poses
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"selfsup": {**TINY, "epochs": 2, "init_fraction": 0.5}}))
    out, rrd = tmp_path / "run", tmp_path / "train.rrd"
    cmd = [
        sys.executable,
        "-m",
        "leovr.cli",
        "train",
        "--mode",
        "selfsup",
        str(seq),
        "--out",
        str(out),
        "--config",
        str(cfg),
    ]
    r = subprocess.run(cmd + ["--rerun", str(rrd)], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr[-2000:]
    log = [json.loads(x) for x in (out / "log.jsonl").read_text().splitlines()]
    assert [x["stage"] for x in log] == ["initialisation", "refinement"]
    assert all(np.isfinite(x["loss"]) and 0 < x["mask_kept"] < 1 for x in log)
    assert (out / "graph" / "refine_e2" / "seq0" / "depth").is_dir()  # the refinement stage re-ran the graph
    assert any((out / "graph" / "init" / "seq0" / "masks").glob("*_prev.png"))
    assert (out / "log.csv").read_text().count("\n") == 3
    depth_model = load_generator(out / "generator.pt")
    assert depth_model.cfg.channels == tuple(TINY["channels"])
    # the trained generator runs in int8 as refine runs it: its own calibration table, depth near floating point
    assert depth_model.int8_ranges is not None
    sample = prepare_sample(open_sequence(seq)[1], CompleteConfig(input="full"))
    frame, sparse = sample.frame, sample.sparse
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "no int8 calibration table" fallback
        int8 = for_inference(depth_model, "onnxruntime_int8")
    d_f = predict_at_focal(for_inference(depth_model, "onnxruntime"), frame.image, sparse, frame.K[0, 0], 130.0)[0]
    d_q = predict_at_focal(int8, frame.image, sparse, frame.K[0, 0], 130.0)[0]
    assert int8.int8_ranges is depth_model.int8_ranges and np.any(d_q != d_f)  # quantised, not the float graph
    assert np.median(np.abs(d_q - d_f) / d_f) < 0.05
    paths = {c.entity_path for c in RrdReader(str(rrd)).stream()}
    assert any(p.endswith("flow_mask_prev") for p in paths) and any(p.endswith("photometric_error") for p in paths)
    assert any(p.endswith("warped_prev") for p in paths)
    # resume: one more epoch continues the log instead of starting over
    r = subprocess.run(cmd + ["--resume", "--epochs", "3"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr[-2000:]
    assert [x["epoch"] for x in map(json.loads, (out / "log.jsonl").read_text().splitlines())] == [1, 2, 3]
    # resuming with other loss settings is refused with the setting's name, and nothing is overwritten
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({"selfsup": {**TINY, "epochs": 2, "init_fraction": 0.5, "target_loss": "l2"}}))
    before = (out / "checkpoint_last.pt").read_bytes()
    r = subprocess.run(cmd[:-1] + [str(other), "--resume", "--epochs", "4"], capture_output=True, text=True, cwd=REPO)
    assert r.returncode != 0 and "target_loss" in r.stderr and "Traceback" not in r.stderr
    assert (out / "checkpoint_last.pt").read_bytes() == before


def test_blind_sequence_hides_ground_truth(dynamic_seq):
    seq = open_sequence(dynamic_seq)
    assert seq[0].depth is not None and seq[0].T_world_cam is not None
    f = BlindSequence(seq)[0]
    assert f.depth is None and f.T_world_cam is None and f.moving_mask is None
    assert f.points is not None and f.image.shape == seq[0].image.shape


def test_oracle_masks_are_the_true_moving_mask_at_training_resolution(dynamic_seq):
    """The benchmark's bound (`train_selfsup(oracle_masks=True)`): each frame's photometric mask is exactly the
    complement of the simulator's moving mask, resampled to the training resolution, in place of every test
    (the config here switches them all off, so without the oracle there would be no mask at all)."""
    from selfsup.supervision import GraphResult, build_supervision, train_frames
    from selfsup.trainer import oracle_moving

    seq = BlindSequence(open_sequence(dynamic_seq))
    cfg = SelfSupConfig(**{**TINY, "max_frames": 4, "flow_mask": False, "rigid_mask": False, "auto_mask": False})
    frames = train_frames(seq, cfg)
    moving = oracle_moving(seq, frames)
    h, w = frames[0].sparse.shape
    truth = seq.base[1].moving_mask
    assert moving[1].shape == (h, w) and truth.shape != (h, w) and truth.any()
    assert abs(moving[1].mean() - truth.mean()) < 0.01  # the same share of moving pixels after resampling
    graph = GraphResult(
        np.stack([np.eye(4)] * 4), list(range(4)), np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, bool), Path("-")
    )
    sup = build_supervision(frames, graph, cfg, False, moving=moving)
    assert np.array_equal(sup.mask_prev[1], ~moving[1]) and np.array_equal(sup.mask_next[1], ~moving[1])
    assert sup.mask_prev[0] is None and sup.mask_next[3] is None
    assert build_supervision(frames, graph, cfg, False).mask_prev[1] is None  # no oracle, no test: no mask


@pytest.mark.slow
def test_ddp_two_processes_keep_equal_weights(dynamic_seq, tmp_path):
    """torchrun with two CPU processes (gloo): after training, both ranks hold the same weights."""
    worker = tmp_path / "worker.py"
    worker.write_text(
        "import sys, torch\nfrom pathlib import Path\nfrom leovr.config import SelfSupConfig\n"
        "from selfsup.trainer import fit\nfrom leovr.pipeline.refine import run_refine\n"
        f"cfg = SelfSupConfig(**{TINY!r}, epochs=1, max_frames=5)\n"
        "_, model = fit(cfg, [Path(sys.argv[1])], Path(sys.argv[2]), run_refine, progress=False)\n"
        "rank = torch.distributed.get_rank()\n"
        "torch.save(model.state_dict(), Path(sys.argv[2]) / f'rank{rank}.pt')\n"
    )
    out = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--nproc-per-node",
            "2",
            "--master-port",
            "29517",
            str(worker),
            str(dynamic_seq),
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=env,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    a, b = (torch.load(out / f"rank{k}.pt") for k in (0, 1))
    for k in a:
        assert torch.equal(a[k], b[k]), k
    from leovr.depth.network import DepthGenerator
    from leovr.depth.train_state import generator_config

    torch.manual_seed(0)
    fresh = DepthGenerator(generator_config(SelfSupConfig(**TINY))).state_dict()
    changed = any(not torch.equal(a[k], fresh[k]) for k in a if a[k].is_floating_point())
    assert changed  # training moved the weights away from the initialisation
    log = json.loads((out / "log.jsonl").read_text().splitlines()[0])
    assert log["processes"] == 2


def test_a_cold_start_begins_at_the_classical_prior():
    """The self-supervised trainer's untrained network returns its classical prior at every pixel (a zero
    residual and an even fusion weight), so a cold start begins at the prior's accuracy, not below it."""
    from leovr.depth.inference import forward_padded
    from leovr.depth.network import DepthGenerator, prior_for
    from leovr.depth.train_state import generator_config

    torch.manual_seed(0)
    sparse = torch.zeros(1, 1, 48, 64)
    hit = torch.rand(1, 1, 48, 64) < 0.05
    sparse[hit] = torch.rand(int(hit.sum())) * 30.0 + 2.0
    image = torch.rand(1, 3, 48, 64)
    cfg = SelfSupConfig(**TINY)
    with torch.no_grad():
        depth, _ = forward_padded(DepthGenerator(generator_config(cfg)).eval(), image, sparse)
        absolute = DepthGenerator(generator_config(cfg.model_copy(update={"output": "absolute"}))).eval()
        depth_absolute, _ = forward_padded(absolute, image, sparse)
    prior = prior_for(sparse)
    assert torch.allclose(depth, prior, rtol=1e-5)
    assert float((depth_absolute / prior - 1).abs().median()) > 0.1  # an untrained absolute network does not


def test_the_masked_lidar_term_scores_returns_hidden_from_the_input(dynamic_seq):
    """Each training frame carries masked-LiDAR splits of its own cheap input: a thinner input and hidden
    returns that are part of the frame's input, on pixels the thinner input leaves empty; the term is zero for depth
    equal to the hidden returns and reads no pixel without one."""
    from selfsup.losses import masked_lidar_loss
    from selfsup.supervision import MASKED_SPLITS, train_frames

    frames = train_frames(BlindSequence(open_sequence(dynamic_seq)), SelfSupConfig(**TINY, max_frames=3))
    for f in frames:
        assert len(f.masked) == MASKED_SPLITS
        for thin, hidden in f.masked:
            assert thin.shape == hidden.shape == f.sparse.shape
            n_thin, n_hidden = int((thin > 0).sum()), int((hidden > 0).sum())
            assert 0 < n_hidden and 0 < n_thin < int((f.sparse > 0).sum())
            assert not ((thin > 0) & (hidden > 0)).any()
            assert (f.sparse[hidden > 0] > 0).all() and (f.sparse[hidden > 0] <= hidden[hidden > 0]).all()
    thin, hidden = (torch.from_numpy(x)[None, None] for x in frames[0].masked[0])
    exact = torch.where(hidden > 0, hidden, torch.full_like(hidden, 50.0))
    assert float(masked_lidar_loss(exact, hidden)) == 0.0
    assert float(masked_lidar_loss(exact * 1.1, hidden)) == pytest.approx(np.log(1.1), rel=1e-4)
    assert float(masked_lidar_loss(torch.where(hidden > 0, exact, exact * 3.0), hidden)) == 0.0
    assert SelfSupConfig(**TINY, weight_masked=0.0).weight_masked == 0.0
    assert (
        train_frames(BlindSequence(open_sequence(dynamic_seq)), SelfSupConfig(**TINY, max_frames=3, weight_masked=0.0))[
            0
        ].masked
        == []
    )


def test_fine_tuning_is_anchored_to_its_starting_network(dynamic_seq, tmp_path):
    """With an init checkpoint every training frame carries the starting network's depth on its own input, and the
    anchor term holds the fine-tuned output near it: the same run without the anchor moves further."""
    from leovr.depth.inference import forward_padded, load_generator
    from leovr.pipeline.refine import run_refine
    from selfsup.losses import anchor_loss
    from selfsup.supervision import train_frames
    from selfsup.trainer import init_network, start_depths, train_selfsup

    cfg = SelfSupConfig(**TINY, max_frames=4, epochs=1, init_fraction=1.0, lr=1e-2)
    train_selfsup(cfg, [dynamic_seq], tmp_path / "start", run_refine, progress=False)
    start = str(tmp_path / "start" / "generator.pt")
    frames = train_frames(BlindSequence(open_sequence(dynamic_seq)), cfg)
    start_depths(init_network(cfg.model_copy(update={"init_checkpoint": start})), frames)
    assert all(f.anchor is not None and f.anchor.shape == f.sparse.shape and (f.anchor > 0).all() for f in frames)
    d0 = torch.from_numpy(frames[1].anchor)[None, None]
    assert float(anchor_loss(d0, d0)) == 0.0 and float(anchor_loss(d0 * 1.2, d0)) == pytest.approx(np.log(1.2), 1e-4)

    def moved(weight: float) -> float:
        """Mean |log D - log D0| of the model fine-tuned with this anchor weight, over the training frames."""
        run = tmp_path / f"anchor_{weight:g}"
        fine = cfg.model_copy(update={"init_checkpoint": start, "weight_anchor": weight, "epochs": 2})
        train_selfsup(fine, [dynamic_seq], run, run_refine, progress=False)
        model = load_generator(run / "generator.pt").eval()
        with torch.no_grad():
            gaps = []
            for f in frames:
                image = torch.from_numpy(np.ascontiguousarray(f.image)).permute(2, 0, 1)[None].float() / 255.0
                depth = forward_padded(model, image, torch.from_numpy(f.sparse)[None, None])[0]
                gaps.append(float(anchor_loss(depth, torch.from_numpy(f.anchor)[None, None])))
        return float(np.mean(gaps))

    free, anchored = moved(0.0), moved(50.0)
    assert anchored < 0.5 * free, (anchored, free)
