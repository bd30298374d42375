"""`leovr adapt`: the masked-LiDAR task, and proof that adaptation reads nothing but the cheap input."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from leovr.cli import app
from leovr.data import open_sequence
from leovr.data.native import NativeWriter
from leovr.depth.network import DepthGenerator, GeneratorConfig
from leovr.errors import DataError
from leovr.lidar.cheap_sensor import parse_input, simulate_cheap_sensor
from leovr.lidar.projection import sparse_depth
from selfsup.masked_lidar import masked_split, stored_rings
from tests.conftest import CX, CY, FX, KITTI_RAW, R_CAM_LIDAR, H, W, needs_shared, ring_scan, write_kitti_raw

runner = CliRunner()
K = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1.0]])
T = np.eye(4)
T[:3, :3] = R_CAM_LIDAR


def test_masked_split_hides_rings_between_kept_rings():
    pts = ring_scan(n_rings=16)
    assert stored_rings(pts) is not None and stored_rings(pts).max() == 15
    every = sparse_depth(pts, K, T, (H, W))
    for seed in range(6):
        sp = masked_split(pts, K, T, (H, W), np.random.default_rng(seed))
        kept, hidden = sp.sparse > 0, sp.target > 0
        assert kept.any() and hidden.any() and not (kept & hidden).any()
        assert (kept | hidden).sum() <= (every > 0).sum()
        rows_kept, rows_hidden = np.unique(np.nonzero(kept)[0]), np.unique(np.nonzero(hidden)[0])
        # hidden rings lie between kept rings (and beyond the last kept one), never on them
        assert not set(rows_hidden) & set(rows_kept)


def test_masked_split_without_rings_hides_beyond_the_input_edge():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(3000, 3)) * [0, 0.04, 0.04] + [1, 0, 0]  # a forward cone, no ring order
    pts = np.concatenate([d / np.linalg.norm(d, axis=1, keepdims=True) * 10, np.ones((3000, 1))], 1)
    assert stored_rings(pts) is None
    sp = masked_split(pts.astype(np.float32), K, T, (H, W), np.random.default_rng(1))
    r_kept = np.hypot(*(np.nonzero(sp.sparse > 0) - np.array([[CY], [CX]])))
    r_hidden = np.hypot(*(np.nonzero(sp.target > 0) - np.array([[CY], [CX]])))
    assert r_hidden.max() > r_kept.max() + 3  # targets outside the thinner input's cone


def small_generator(path):
    torch.manual_seed(0)
    net = DepthGenerator(GeneratorConfig(output="fusion", channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1)))
    torch.save({"model": net.state_dict(), "network": net.cfg.__dict__}, path)
    return path


@pytest.mark.slow
def test_adapt_reads_only_the_cheap_input(tmp_path):
    """Adapting with --input vlp16 on a drive gives the very same weights as adapting with --input full
    on a copy that holds only the VLP-16 rings: the 48 held-out rings (the evaluation beams) are never read."""
    drive = write_kitti_raw(tmp_path / "raw", frames=4)
    seq = open_sequence(drive)
    w = NativeWriter(tmp_path / "cheap")
    for i in range(len(seq)):
        f = seq[i]
        kept = simulate_cheap_sensor(f.points, parse_input("vlp16"), f.index, 0, f.K, f.T_cam_lidar, f.shape).kept
        assert 0 < len(kept) < len(f.points)
        w.write(replace(f, points=kept))
    cheap = w.close()
    init = small_generator(tmp_path / "init.pt")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("adapt:\n  generator_focal_px: null\n  val_every: 4\n  batch_size: 3\n  splits_per_frame: 2\n")
    outs = {}
    for name, data, inp in (("raw", drive, "vlp16"), ("cheap", cheap, "full")):
        outs[name] = tmp_path / f"out_{name}"
        r = runner.invoke(
            app,
            [
                "adapt",
                str(data),
                "--out",
                str(outs[name]),
                "--input",
                inp,
                "--init",
                str(init),
                "--epochs",
                "1",
                "-c",
                str(cfg),
            ],
        )
        assert r.exit_code == 0, r.output
    start = torch.load(init, weights_only=False)["model"]
    for name in ("generator.pt", "checkpoint_last.pt"):  # best-validation and last weights
        a = torch.load(outs["raw"] / name, weights_only=False)
        b = torch.load(outs["cheap"] / name, weights_only=False)
        assert a["epoch"] == b["epoch"]
        for k in a["model"]:
            assert torch.equal(a["model"][k], b["model"][k]), (name, k)
    assert any(not torch.equal(a["model"][k], start[k]) for k in start)  # it did train
    # the int8 runtime's table, measured on the adapted weights over the same cheap input
    ranges = [torch.load(outs[n] / "generator.pt", weights_only=False)["int8_ranges"] for n in ("raw", "cheap")]
    assert ranges[0] == ranges[1] and len(ranges[0]["data"]) > 10
    log = [json.loads(line) for line in (outs["raw"] / "log.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in log] == [0, 1]
    # resume continues to a second epoch; other settings are refused
    r = runner.invoke(
        app,
        [
            "adapt",
            str(drive),
            "--out",
            str(outs["raw"]),
            "--input",
            "vlp16",
            "--init",
            str(init),
            "--epochs",
            "2",
            "-c",
            str(cfg),
            "--resume",
        ],
    )
    assert r.exit_code == 0, r.output
    assert json.loads((outs["raw"] / "log.jsonl").read_text().splitlines()[-1])["epoch"] == 2
    r = runner.invoke(
        app,
        [
            "adapt",
            str(drive),
            "--out",
            str(outs["raw"]),
            "--input",
            "mid40",
            "--init",
            str(init),
            "--epochs",
            "4",
            "-c",
            str(cfg),
            "--resume",
        ],
    )
    assert isinstance(r.exception, DataError) and 'settings.input (folder: "vlp16", now: "mid40")' in str(r.exception)
    # a truncated resume checkpoint (an interrupted copy) is one clear error, not torch's
    last = outs["raw"] / "checkpoint_last.pt"
    last.write_bytes(last.read_bytes()[:1000])
    r = runner.invoke(
        app,
        [
            "adapt",
            str(drive),
            "--out",
            str(outs["raw"]),
            "--input",
            "vlp16",
            "--init",
            str(init),
            "--epochs",
            "3",
            "-c",
            str(cfg),
            "--resume",
        ],
    )
    assert isinstance(r.exception, DataError) and "checkpoint_last.pt: unreadable checkpoint (truncated" in str(
        r.exception
    )


@pytest.mark.slow
def test_adapt_on_two_processes_matches_one(tmp_path):
    """`torchrun --nproc-per-node 2 leovr adapt ...` (DistributedDataParallel over gloo, each process a
    share of the batch and of the validation frames) takes the same steps as one process: same
    weights after two epochs, same validation MAE, and only process 0 writes."""
    import os
    import subprocess
    import sys

    drive = write_kitti_raw(tmp_path / "raw", frames=6)
    init = small_generator(tmp_path / "init.pt")
    cfg = tmp_path / "c.yaml"
    # frame 3 validates; the other five form a batch of 4 (2 per process) and a batch of 1 (one process
    # takes it, the other joins the step at weight 0): two epochs, four steps
    cfg.write_text("adapt:\n  generator_focal_px: null\n  val_every: 6\n  batch_size: 4\n  splits_per_frame: 2\n")
    args = ["adapt", str(drive), "--input", "vlp16", "--init", str(init), "--epochs", "2", "-c", str(cfg)]
    one = tmp_path / "one"
    r = runner.invoke(app, [*args, "--out", str(one)])
    assert r.exit_code == 0, r.output
    two = tmp_path / "two"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc-per-node",
            "2",
            "-m",
            "leovr.cli",
            *args,
            "--out",
            str(two),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    log1 = [json.loads(line) for line in (one / "log.jsonl").read_text().splitlines()]
    log2 = [json.loads(line) for line in (two / "log.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in log2] == [0, 1, 2]  # one writer: no line twice
    assert [r.get("processes") for r in log2] == [2, 2, 2] and log1[-1]["processes"] == 1
    for a, b in zip(log1, log2):
        assert abs(a["val_mae_m"] - b["val_mae_m"]) <= 1e-4 * a["val_mae_m"]
    start = torch.load(init, weights_only=False)["model"]
    a = torch.load(one / "checkpoint_last.pt", weights_only=False)["model"]
    b = torch.load(two / "checkpoint_last.pt", weights_only=False)["model"]
    moved = max(float((a[k].float() - start[k].float()).abs().max()) for k in a)
    assert moved > 1e-4  # it trained
    for k in a:
        assert torch.allclose(a[k].float(), b[k].float(), rtol=1e-3, atol=1e-5 * max(moved, 1.0)), k


@pytest.mark.slow
def test_adapt_on_two_processes_stops_together_on_a_bad_output_folder(tmp_path):
    """Process 0 alone checks and records the output folder; when it cannot be written, every process
    stops with the error instead of waiting for process 0 in the next collective."""
    import os
    import subprocess
    import sys

    drive = write_kitti_raw(tmp_path / "raw", frames=3)
    init = small_generator(tmp_path / "init.pt")
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("a file where the output folder should be\n")
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nproc-per-node",
            "2",
            "-m",
            "leovr.cli",
            "adapt",
            str(drive),
            "--input",
            "vlp16",
            "--init",
            str(init),
            "--epochs",
            "1",
            "--out",
            str(blocker),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=120,
    )
    assert p.returncode != 0
    # each process prints the one-line error (torchrun then adds its own launcher report)
    assert (p.stdout + p.stderr).count(f"error: {blocker}: output path is a file") == 2


def test_adapt_blend_falls_back_to_the_prior_where_the_network_is_worse(tmp_path):
    """choose_blend weighs the network's log depth against its prior's at the validation frames' hidden
    returns: a network that returns its prior ties (and keeps weight 1); one that puts everything 65 %
    too far loses to its prior, and the chosen blend is what inference then returns."""
    from selfsup.adapt import choose_blend
    from selfsup.adapt_data import input_frames
    from leovr.config import AdaptConfig
    from leovr.depth.inference import predict
    from leovr.depth.prior import interpolated_fill

    drive = write_kitti_raw(tmp_path / "raw", frames=2)
    frames = input_frames(
        [open_sequence(drive)], AdaptConfig(input="vlp16", generator_focal_px=None, splits_per_frame=2), progress=False
    )
    torch.manual_seed(0)
    net = DepthGenerator(GeneratorConfig(output="residual", channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))).eval()
    w, mae = choose_blend(net, frames)
    assert w == 1.0 and max(mae.values()) - min(mae.values()) < 1e-4  # zero residual: every blend is the prior
    with torch.no_grad():
        net.depth_head.bias.fill_(0.5)
    w, mae = choose_blend(net, frames)
    assert w == 0.0 and mae[0.0] < mae[0.5] < mae[1.0] and net.cfg.blend == 1.0
    f = open_sequence(drive)[0]
    sparse = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
    net.cfg = replace(net.cfg, blend=0.0)
    np.testing.assert_allclose(
        predict(net, f.image, sparse, image_edges=False)[0], interpolated_fill(sparse), rtol=1e-4
    )
    with pytest.raises(ValueError, match="blend"):
        GeneratorConfig(blend=1.5)


@pytest.mark.slow
@needs_shared
def test_adaptation_learns_the_masked_task_on_real_frames(tmp_path):
    """Real KITTI frames, Mid-40-like input: four epochs from the shipped generator lower the error at the
    training frames' hidden returns (every split, the network alone; measured 0.901 -> 0.859 m; two epochs leave
    a gain that depends on the CPU's arithmetic, under 1 % on some)."""
    from leovr.config import AdaptConfig
    from leovr.depth.inference import load_generator
    from leovr.paths import shipped_checkpoint
    from selfsup.adapt import adapt, validate
    from selfsup.adapt_data import input_frames

    seq = open_sequence(KITTI_RAW)[:12]
    cfg = AdaptConfig(input="mid40", val_every=0, epochs=4, splits_per_frame=2)
    frames = input_frames([seq], cfg, progress=False)
    model = load_generator(shipped_checkpoint())
    model.cfg = replace(model.cfg, blend=1.0)
    before = validate(model, frames)
    adapt([seq], cfg, tmp_path / "out", progress=False)
    model.load_state_dict(torch.load(tmp_path / "out" / "checkpoint_last.pt", weights_only=False)["model"])
    after = validate(model, frames)
    assert after < 0.98 * before, (before, after)


def test_adapt_on_too_few_frames_to_validate_says_how_many_it_needs_and_writes_no_infinity(tmp_path):
    """Two frames cannot hold one out for validation (every 8th, from the 5th): refused with the count needed;
    with validation off it adapts, and its log and summary hold plain numbers or null, never NaN / Infinity."""
    drive = write_kitti_raw(tmp_path / "raw", frames=2)
    init = small_generator(tmp_path / "init.pt")
    base = ["adapt", str(drive), "--input", "vlp16", "--init", str(init), "--epochs", "1"]
    r = runner.invoke(app, base + ["--out", str(tmp_path / "a")])
    assert isinstance(r.exception, DataError) and "needs at least 5" in str(r.exception)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("adapt:\n  generator_focal_px: null\n  val_every: 0\n  splits_per_frame: 1\n")
    r = runner.invoke(app, base + ["--out", str(tmp_path / "b"), "-c", str(cfg)])
    assert r.exit_code == 0, r.output
    assert "no validation frames" in r.output

    def strict(text: str):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} written"))

    log = [strict(line) for line in (tmp_path / "b" / "log.jsonl").read_text().splitlines()]
    assert log[0]["val_mae_m"] is None and log[1]["best_val_mae_m"] is None
    strict((tmp_path / "b" / "summary.json").read_text())
