"""The command line end to end: info, complete (with resume and config), convert, errors, bench."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import KITTI_RAW, needs_shared, write_kitti_raw
from typer.testing import CliRunner

from leovr.cli import app
from leovr.config import LeovrConfig, RefineConfig, load_config, override
from leovr.errors import ConfigError
from leovr.paths import REPO_ROOT

runner = CliRunner()


def test_default_yaml_matches_built_in_defaults():
    from leovr.bench.config import BenchConfig, load_bench_config

    assert load_config(REPO_ROOT / "configs" / "default.yaml") == LeovrConfig()
    assert load_bench_config(REPO_ROOT / "configs" / "bench.yaml") == BenchConfig()


def test_the_products_config_holds_no_benchmark_section_and_a_bench_config_is_checked():
    from leovr.bench.config import load_bench_config
    from leovr.errors import ConfigError

    assert not [key for key in LeovrConfig.model_fields if key.startswith("bench")]
    bad = REPO_ROOT / "configs" / "default.yaml"  # the product's sections are no benchmark's
    with pytest.raises(ConfigError, match="default.yaml"):
        load_bench_config(bad)


def test_config_rejects_unknown_keys_and_bad_values(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text("complete:\n  metod: nearest\n")
    with pytest.raises(ConfigError, match="metod"):
        load_config(bad)
    bad.write_text("complete:\n  input: ratio:0.9\n")
    with pytest.raises(ConfigError, match="outside"):
        load_config(bad)
    bad.write_text("refine:\n  graph:\n    pixel_sigm: 2.0\n")  # a misspelt key of a nested table: named in full
    with pytest.raises(ConfigError, match=r"refine\.graph\.pixel_sigm"):
        load_config(bad)
    bad.write_text("refine:\n  loop_closure: true\n")  # a key of the flat layout before the nested tables
    with pytest.raises(ConfigError, match="refine.loop_closure"):
        load_config(bad)


def test_a_nested_table_in_yaml_changes_only_the_keys_it_names(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text(
        "refine:\n  window: 6\n  graph:\n    pixel_sigma: 2.0\n  camera_only:\n    graph:\n"
        "      landmark_prior_rel: 5.0\n"
    )
    cfg = load_config(path).refine
    assert cfg.window == 6 and cfg.graph.pixel_sigma == 2.0 and cfg.camera_only.graph.landmark_prior_rel == 5.0
    default = RefineConfig()
    assert cfg.graph.model_copy(update={"pixel_sigma": default.graph.pixel_sigma}) == default.graph
    assert cfg.camera_only.graph.consistency_sigma_log == default.camera_only.graph.consistency_sigma_log


def test_override_merges_nested_options_and_skips_the_ones_not_given():
    base = RefineConfig(graph={"pixel_sigma": 2.0}, loop={"min_gap": 40})
    cfg = override(base, window=6, loop={"enabled": True}, graph={"pixel_sigma": None}, causal=None)
    assert cfg.window == 6 and cfg.loop.enabled and cfg.loop.min_gap == 40 and cfg.graph == base.graph
    assert override(base, loop={"enabled": None}) == base
    with pytest.raises(ConfigError, match=r"loop\.min_gap"):
        override(base, loop={"min_gap": 1})
    with pytest.raises(ConfigError, match="causal run"):
        override(base, causal=True, loop={"enabled": True})


def test_one_seed_at_the_top_level_seeds_every_section_and_a_sections_own_is_refused(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("seed: 7\nrefine:\n  window: 6\n")
    cfg = load_config(path)
    seeded = ("complete", "simulate", "demo", "train", "refine", "selfsup")
    assert [getattr(cfg, key).seed for key in seeded] == [7] * len(seeded) and cfg.refine.window == 6
    assert [getattr(override(cfg, seed=3), key).seed for key in seeded] == [3] * len(seeded)  # --seed
    assert "seed" not in cfg.model_dump()["refine"] and cfg.model_dump()["seed"] == 7  # held once, as in the file
    path.write_text("seed: 7\ntrain:\n  seed: 2\n")
    with pytest.raises(ConfigError, match=r"c\.yaml: train\.seed: the seed is set once, at the top level"):
        load_config(path)


def test_refine_flags_set_the_nested_settings(tmp_path, monkeypatch):
    """--loop-closure sets refine.loop.enabled beside the top-level flags, over the config file's values."""
    import leovr.cli as cli

    seen = []
    monkeypatch.setattr(cli, "_run_refine", lambda data, out, cfg, resume, rerun: seen.append(cfg))
    path = tmp_path / "c.yaml"
    path.write_text("refine:\n  loop:\n    min_gap: 50\n  graph:\n    pixel_sigma: 2.0\n")
    r = runner.invoke(
        app,
        [
            "refine",
            str(tmp_path),
            "-o",
            str(tmp_path / "o"),
            "-c",
            str(path),
            "--loop-closure",
            "--window",
            "6",
            "--input",
            "vlp16",
            "--end",
            "9",
        ],
    )
    assert r.exit_code == 0, r.output
    cfg = seen[-1]
    assert cfg.loop.enabled and cfg.loop.min_gap == 50 and cfg.graph.pixel_sigma == 2.0
    assert (cfg.window, cfg.input, cfg.end, cfg.causal) == (6, "vlp16", 9, False)
    r = runner.invoke(app, ["poses", str(tmp_path), "-o", str(tmp_path / "p"), "--no-loop-closure", "--compare"])
    assert r.exit_code == 0, r.output
    assert not seen[-1].loop.enabled and seen[-1].compare
    r = runner.invoke(app, ["refine", str(tmp_path), "-o", str(tmp_path / "o"), "--causal", "--loop-closure"])
    assert isinstance(r.exception, ConfigError) and "causal run" in str(r.exception)


def test_info_prints_summary(kitti_raw_tiny):
    r = runner.invoke(app, ["info", str(kitti_raw_tiny), "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output)
    assert info["reader"] == "kitti_raw" and info["frames"] == 3 and info["points_per_scan"] == 64 * 360


def test_complete_writes_uint16_png_metrics_and_resumes(kitti_raw_tiny, tmp_path):
    out = tmp_path / "out"
    cfg = tmp_path / "c.yaml"
    cfg.write_text("complete:\n  method: nearest\n  input: vlp16\n")
    r = runner.invoke(app, ["complete", str(kitti_raw_tiny), "--out", str(out), "--config", str(cfg), "--end", "2"])
    assert r.exit_code == 0, r.output
    m = json.loads((out / "metrics.json").read_text())
    assert m["method"] == "nearest" and m["input"] == "vlp16" and m["frames"] == 2
    png = cv2.imread(str(out / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and png.shape == (80, 160)
    # the tiny world is a 10 m sphere: depth (camera z) lies in 9.1-10 m across this 44-degree view,
    # written as metres x 256 (KITTI depth-completion convention), the scale recorded in run.json
    assert png.min() > 9.1 * 256 and png.max() <= 10.05 * 256 and m["mae_m"] < 0.1
    assert json.loads((out / "run.json").read_text())["depth_png"]["scale"] == 256
    # option on the command line beats the config file
    r = runner.invoke(
        app, ["complete", str(kitti_raw_tiny), "-o", str(out / "b"), "-c", str(cfg), "--method", "ipbasic"]
    )
    assert json.loads((out / "b" / "metrics.json").read_text())["method"] == "ipbasic"
    # resume: a frame already written is read back, not recomputed
    marker = np.full_like(png, 12_345)  # 48.2 m
    cv2.imwrite(str(out / "depth" / "000001.png"), marker)
    r = runner.invoke(
        app, ["complete", str(kitti_raw_tiny), "--out", str(out), "-c", str(cfg), "--end", "2", "--resume"]
    )
    assert r.exit_code == 0, r.output
    assert json.loads((out / "metrics.json").read_text())["mae_m"] > 1.0
    assert (cv2.imread(str(out / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED) == 12_345).all()


@pytest.mark.slow
def test_resume_refuses_a_folder_another_run_wrote(kitti_raw_tiny, tmp_path):
    """--resume continues only the run that wrote the folder: another method, input, sequence or a
    folder without run.json is refused with the difference named, and nothing in it is touched."""
    out = tmp_path / "out"
    base = ["complete", str(kitti_raw_tiny), "--out", str(out), "--method", "nearest", "--input", "vlp16", "--end", "2"]
    assert runner.invoke(app, base).exit_code == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other = tmp_path / "other"
    write_kitti_raw(other, frames=3)
    for args, named in [
        (["--method", "ipbasic"], 'settings.method (folder: "nearest", now: "ipbasic")'),
        (["--input", "mid40"], 'settings.input (folder: "vlp16", now: "mid40")'),
        (["--end", "3"], "settings.end (folder: 2, now: 3)"),
    ]:
        cmd = base + args + ["--resume"]
        r = subprocess.run(
            [sys.executable, "-c", "from leovr.cli import main; main()", *cmd], capture_output=True, text=True
        )
        assert r.returncode == 2 and named in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = runner.invoke(app, ["complete", str(other), *base[2:], "--resume"])
    assert r.exit_code != 0 and "sequences[0].path" in str(r.exception)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    (out / "run.json").unlink()
    r = runner.invoke(app, base + ["--resume"])
    assert r.exit_code != 0 and "no run.json" in str(r.exception)
    old = os.umask(0o022)  # files honour the user's umask (0666 & ~umask), not mkstemp's 0600
    try:
        assert runner.invoke(app, base).exit_code == 0  # without --resume the folder is simply rewritten
    finally:
        os.umask(old)
    for p in ("run.json", "metrics.json", "depth/000001.png"):
        assert (out / p).stat().st_mode & 0o777 == 0o644, p


def test_convert_then_info(kitti_raw_tiny, tmp_path):
    r = runner.invoke(app, ["convert", str(kitti_raw_tiny), "--out", str(tmp_path / "n")])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["info", str(tmp_path / "n")])
    assert "native" in r.output


def test_user_errors_are_one_line_with_exit_code_2(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-c", "from leovr.cli import main; main()", "info", str(tmp_path / "missing")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"error: {tmp_path / 'missing'}: no such file or folder"
    assert "Traceback" not in proc.stderr


def test_complete_refuses_sequence_without_lidar(tmp_path):
    from leovr.data import Frame, NativeWriter

    w = NativeWriter(tmp_path / "s")
    w.write(Frame(0, 0.0, np.zeros((8, 8, 3), np.uint8), np.eye(3)))
    w.close()
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "complete",
            str(tmp_path / "s"),
            "-o",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "has no LiDAR" in proc.stderr


@needs_shared
def test_bench_baseline_quick_contract(tmp_path):
    out = tmp_path / "b.json"
    run = runner.invoke(app, ["bench", "baseline", "--quick", "--out", str(out)])
    assert run.exit_code == 0, run.output
    doc = json.loads(out.read_text())
    assert set(doc["results"]) == {"kitti_vlp16", "kitti_mid40"}
    for per_input in doc["results"].values():
        assert set(per_input) == {"nearest", "ipbasic", "interp"}
        for r in per_input.values():
            assert {"mae_m", "rmse_m", "absrel", "delta1", "ms_per_frame", "bins"} <= set(r)
            assert 0.1 < r["mae_m"] < 10 and r["rmse_m"] >= r["mae_m"] and 0 < r["delta1"] <= 1
            assert set(r["bins"]) == {"0-20", "20-40", "40-60", "60-80", ">80"}
    # the denser VLP-16 input must beat Mid-40 (a narrow cone) for the same method
    assert doc["results"]["kitti_vlp16"]["nearest"]["mae_m"] < doc["results"]["kitti_mid40"]["nearest"]["mae_m"]
    # the command prints the tables docs/benchmarks.md shows for this bench
    assert (
        "## baseline" in run.output
        and f"| kitti_vlp16 | nearest | {doc['results']['kitti_vlp16']['nearest']['mae_m']:.3f} |" in run.output
    )


@pytest.mark.slow
@needs_shared
def test_demo_writes_report(tmp_path):
    r = runner.invoke(app, ["demo", "--out", str(tmp_path), "--frames", "3", "--data", str(KITTI_RAW)])
    assert r.exit_code == 0, r.output
    report = (tmp_path / "report.md").read_text()
    assert "| ipbasic |" in report and "| refined |" in report and "held-out" in report
    assert len(list((tmp_path / "refine" / "depth").glob("*.png"))) == 3


@pytest.mark.slow
def test_simulate_command_and_bad_option(tmp_path):
    r = runner.invoke(
        app,
        [
            "simulate",
            "--out",
            str(tmp_path / "s"),
            "--frames",
            "2",
            "--lidar",
            "vlp16",
            "--scenario",
            "straight",
            "--preview",
        ],
    )
    assert r.exit_code == 0, r.output
    info = json.loads(runner.invoke(app, ["info", str(tmp_path / "s"), "--json"]).output)
    assert info["frames"] == 2 and info["has_depth"] and info["has_poses"] and info["has_point_times"]
    assert (info["width"], info["height"]) == (448, 256) and (tmp_path / "s" / "preview.png").is_file()
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "simulate",
            "-o",
            str(tmp_path / "x"),
            "--light",
            "noon",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and proc.stderr.startswith("error: invalid option: light:")


def test_bench_simulate_contract(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("simulate:\n  frames: 1\n  lidars: [mid40]\n")
    r = runner.invoke(app, ["bench", "simulate", "--out", str(tmp_path / "b.json"), "-c", str(cfg)])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "b.json").read_text())
    assert doc["lidar"] == "mid40" and (doc["width"], doc["height"]) == (448, 256) and doc["frames_per_s"] > 0


@pytest.mark.slow
def test_demo_on_generated_default(tmp_path):
    r = runner.invoke(app, ["demo", "--out", str(tmp_path), "--frames", "3"])
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ground_truth"].startswith("dense") and m["frames"] == 3
    assert list(m["depth"]) == [
        "raw",
        "nearest",
        "ipbasic",
        "nearest_accumulated",
        "ipbasic_accumulated",
        "generator",
        "generator_frame",
        "refined",
    ]
    assert m["depth"]["refined"]["n"] > 150_000  # dense ground truth: most of 3 x 448 x 256 pixels
    # city loop: loop closure on; the rendered scans carry point times, so KISS-ICP runs with and without its deskew
    assert set(m["trajectory"]) == {"leovr", "leovr_no_loop", "kiss_icp", "kiss_icp_no_deskew"}
    for f in (
        "sequence/preview.png",
        "mae_by_distance.png",
        "trajectory.png",
        "map.png",
        "refine/map/map.ply",
        "demo.rrd",
        "report.md",
    ):
        assert (tmp_path / f).is_file(), f
    assert (
        m["map"]["frames"] == 3
        and m["map"]["triangles"] > 1000
        and "`refine/map/map.ply`" in (tmp_path / "report.md").read_text()
    )


@pytest.mark.slow
def test_complete_with_generator_checkpoint_and_missing_checkpoint(kitti_raw_tiny, tmp_path):
    import torch

    from leovr.depth.network import DepthGenerator, GeneratorConfig

    torch.manual_seed(0)
    cfg = GeneratorConfig(channels=(8, 8, 16, 16, 16), blocks=(1, 1, 1, 1))
    ckpt = tmp_path / "g.pt"
    torch.save({"model": DepthGenerator(cfg).state_dict(), "network": cfg.__dict__}, ckpt)
    r = runner.invoke(
        app,
        [
            "complete",
            str(kitti_raw_tiny),
            "-o",
            str(tmp_path / "o"),
            "--method",
            "generator",
            "--checkpoint",
            str(ckpt),
            "--input",
            "vlp16",
            "--end",
            "1",
        ],
    )
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["method"] == "generator" and m["n"] > 0 and m["mae_m"] > 0
    png = cv2.imread(str(tmp_path / "o" / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert png.shape == (80, 160) and (png > 0).all()
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "complete",
            str(kitti_raw_tiny),
            "-o",
            str(tmp_path / "p"),
            "--method",
            "generator",
            "--checkpoint",
            str(tmp_path / "none.pt"),
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "depth-generator checkpoint not found" in proc.stderr


def test_a_causal_run_with_loop_closure_is_refused_in_one_line(tmp_path):
    """A check across settings names what is wrong, without pydantic's prefixes or an empty location."""
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "refine",
            str(tmp_path / "seq"),
            "-o",
            str(tmp_path / "o"),
            "--causal",
            "--loop-closure",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("error: invalid option: loop.enabled corrects the whole recording afterwards"), r.stderr
