"""`leovr batch` on a real local Ray instance (no mocks): three small rendered sequences and a corrupt
one with two workers; a worker killed by its PID mid-batch; manifests."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from leovr.config import LeovrConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png
from leovr.errors import ConfigError, DataError
from leovr.pipeline.batch import run_batch
from leovr.pipeline.batch_manifest import read_batch
from leovr.pipeline.refine import run_refine
from leovr.sim.simulate import simulate

pytest.importorskip("ray")


def _render(root: Path, frames: int) -> Path:
    for n in range(3):
        simulate(
            SimulateConfig(scenario="city_loop", lidar="mid40", frames=frames, seed=3310 + n),
            root / f"drive{n}",
            progress=False,
        )
    return root


@pytest.fixture(scope="module")
def drives(tmp_path_factory) -> Path:
    root = _render(tmp_path_factory.mktemp("batch") / "drives", 6)
    bad = root / "drive_corrupt"
    shutil.copytree(root / "drive0", bad)
    img = sorted((bad / "images").iterdir())[3]
    img.write_bytes(img.read_bytes()[:200])  # a truncated PNG: frame 3 cannot be decoded
    return root


def _rows(out: Path) -> dict[str, dict]:
    with open(out / "summary.csv") as fh:
        return {r["name"]: r for r in csv.DictReader(fh)}


def _same_run(a: Path, b: Path) -> None:
    """Same poses (to 1e-5 m) and the same depth PNGs up to one 1/256 m step at a rare pixel, the
    repeatability of two single-process runs (test_refine)."""
    pa, pb = (np.loadtxt(d / "poses_kitti.txt") for d in (a, b))
    assert pa.shape == pb.shape and np.abs(pa - pb).max() < 1e-5
    pngs = sorted((a / "depth").glob("*.png"))
    assert [p.name for p in pngs] == sorted(p.name for p in (b / "depth").glob("*.png"))
    for p in pngs:
        da, db = read_depth_png(p), read_depth_png(b / "depth" / p.name)
        diff = np.abs(da - db)
        assert diff.max() <= 1.5 / 256 and (diff > 0).mean() < 1e-3


@pytest.mark.slow
def test_batch_of_three_and_a_corrupt_sequence_on_two_workers(drives, tmp_path):
    out = tmp_path / "out"
    cfg = LeovrConfig()
    cfg.batch.workers = 2
    rows = run_batch(read_batch(drives), cfg, out, progress=False)
    assert {r["name"]: r["status"] for r in rows} == {
        "drive0": "done",
        "drive1": "done",
        "drive2": "done",
        "drive_corrupt": "failed",
    }
    summary = _rows(out)
    assert "000003.png" in summary["drive_corrupt"]["error"] and "decode" in summary["drive_corrupt"]["error"]
    for name in ("drive0", "drive1", "drive2"):
        assert summary[name]["frames"] == "6" and float(summary[name]["mae_refined_m"]) > 0
        assert float(summary[name]["graph_ms"]) > 0 and float(summary[name]["ate_m"]) >= 0
    assert "drive_corrupt | failed" in (out / "summary.md").read_text()
    assert (out / "mae_per_sequence.png").stat().st_size > 1000
    # each sequence's outputs are what a single-process `leovr refine` writes
    for name in ("drive0", "drive1", "drive2"):
        run_refine(open_sequence(drives / name), RefineConfig(), tmp_path / f"single_{name}", progress=False)
        _same_run(out / name, tmp_path / f"single_{name}")
        single = json.loads((tmp_path / f"single_{name}" / "metrics.json").read_text())["depth"]["refined"]["mae_m"]
        assert float(summary[name]["mae_refined_m"]) == pytest.approx(single, abs=1e-3)
    # a second run does the three again only if their settings changed; the corrupt one is tried again
    rows = run_batch(read_batch(drives), cfg, out, progress=False)
    assert [r["status"] for r in rows] == ["skipped", "skipped", "skipped", "failed"]


@pytest.mark.slow
def test_a_killed_worker_loses_nothing_and_a_rerun_does_no_work(tmp_path):
    drives = _render(tmp_path / "drives", 14)
    out = tmp_path / "out"
    cmd = [str(Path(sys.executable).parent / "leovr"), "batch", str(drives), "--out", str(out), "--workers", "2"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    killed = None
    deadline = time.time() + 240
    while killed is None and proc.poll() is None and time.time() < deadline:
        for d in sorted(out.glob("drive*")):
            st, prog = d / "batch.json", d / "progress.json"
            try:
                state = json.loads(st.read_text())
                done = len(json.loads(prog.read_text())["poses"])
            except (OSError, ValueError, KeyError):
                continue
            if state.get("status") == "running" and 1 <= done < 14:  # frames finished, more in flight
                os.kill(state["pid"], signal.SIGKILL)
                killed = d.name
                break
        time.sleep(0.05)
    log, _ = proc.communicate(timeout=600)
    assert killed is not None, "no worker was caught mid-sequence: " + log[-2000:]
    assert proc.returncode == 0, log[-2000:]
    rows = _rows(out)
    assert {r["status"] for r in rows.values()} == {"done"}, rows
    assert json.loads((out / killed / "batch.json").read_text())["attempts"] == 2
    for name in rows:
        assert len((out / name / "poses_kitti.txt").read_text().splitlines()) == 14
        assert len(list((out / name / "depth").glob("*.png"))) == 14
        assert json.loads((out / name / "metrics.json").read_text())["frames"] == 14
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file() and p.parent != out}
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0 and "0 done, 3 skipped, 0 failed" in again.stdout, again.stdout + again.stderr
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # nothing rewritten


def test_manifests_yaml_csv_and_bad_entries(tmp_path, drives):
    y = tmp_path / "m.yaml"
    y.write_text(
        f"sequences:\n  - {drives / 'drive0'}\n  - path: {drives / 'drive1'}\n    name: second\n    end: 3\n"
        f"  - path: {drives / 'drive0'}\n"
    )
    items = read_batch(y)
    assert [it.name for it in items] == ["drive0", "second", "drive0_2"]
    assert items[1].options == {"end": 3}
    c = drives.parent / "m.csv"  # relative paths are taken from the manifest's folder
    c.write_text("path,name,end,input\ndrives/drive2,,4,\n")
    (it,) = read_batch(c)
    assert it.path.resolve() == (drives / "drive2").resolve() and it.options == {"end": 4}
    with pytest.raises(DataError, match="needs a path"):
        y.write_text("- name: x\n")
        read_batch(y)
    with pytest.raises(DataError, match="no sequence found"):
        (tmp_path / "empty").mkdir()
        read_batch(tmp_path / "empty")
    # a bad per-sequence option (a value out of range, a typo) refuses the batch before any work, naming each
    y.write_text(f"- path: {drives / 'drive1'}\n  window: 1\n- path: {drives / 'drive2'}\n  colour: red\n")
    with pytest.raises(ConfigError, match=r"nothing run: drive1: .*window.*; drive2: .*unknown option\(s\) colour"):
        run_batch(read_batch(y), LeovrConfig(), tmp_path / "out", progress=False)
    assert not (tmp_path / "out" / "drive1").exists()


@pytest.mark.slow
def test_bench_batch_contract(tmp_path):
    from leovr.bench.batch import run_batch_bench

    from leovr.bench.config import BenchBatchConfig

    doc = run_batch_bench(tmp_path / "batch.json", BenchBatchConfig(sequences=2, frames=3), progress=False)
    assert json.loads((tmp_path / "batch.json").read_text()) == doc
    assert doc["sequences"] == 2 and doc["frames"] == 6 and set(doc["wall_s"]) == {"1", "2"}
    assert doc["speedup"] == pytest.approx(doc["wall_s"]["1"] / doc["wall_s"]["2"], rel=1e-2)
    assert doc["frames_per_core_hour"] == pytest.approx(6 * 3600 / (2 * doc["wall_s"]["2"]), rel=1e-2)
    t1, t2 = doc["task_s_sum"]["1"], doc["task_s_sum"]["2"]
    assert 0 < t1 < doc["wall_s"]["1"] and 0 < t2 / 2 < doc["wall_s"]["2"]  # Ray's start and stop cost something
    assert doc["ceiling_speedup"] == pytest.approx(2 * t1 / t2, rel=1e-2)
    assert doc["fixed_s"]["2"] == pytest.approx(doc["wall_s"]["2"] - t2 / 2, abs=0.02)
    for w in ("workers1", "workers2"):
        assert _rows(tmp_path / "batch_work" / w).keys() == {"drive0", "drive1"}


@contextmanager
def process_threads():
    """A batch task run in this process sets its torch and OpenCV threads; the later tests need theirs back."""
    import cv2
    import torch

    threads = torch.get_num_threads(), cv2.getNumThreads()
    try:
        yield
    finally:
        torch.set_num_threads(threads[0])
        cv2.setNumThreads(threads[1])


def test_a_rerun_with_other_settings_is_refused_before_any_work(drives, tmp_path):
    """A batch whose output folder holds a sequence's results from other settings is refused in one line
    naming the sequence and the difference, before any work and without touching those results."""
    from leovr.pipeline.batch import check_no_other_results, job_section, run_sequence, task_settings
    from leovr.pipeline.batch_manifest import BatchItem

    item = BatchItem("drive0", drives / "drive0")
    section = {
        end: job_section(LeovrConfig.model_validate({"complete": {"end": end}}), "complete", item) for end in (3, 2)
    }
    with process_threads():
        assert run_sequence(item, "complete", section[3], tmp_path / "drive0")["status"] == "done"
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*") if p.is_file()}
    # same: passes
    check_no_other_results(tmp_path, [item], {"drive0": task_settings("complete", section[3], item.path)})
    with pytest.raises(
        DataError, match=r"results of other settings or input files for drive0: config.end \(folder: 3, now: 2\)"
    ):
        check_no_other_results(tmp_path, [item], {"drive0": task_settings("complete", section[2], item.path)})
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


@pytest.mark.slow
def test_a_refine_task_fuses_its_map_when_asked(drives, tmp_path):
    """`batch.map`: each refined sequence also gets its map (OUT/NAME/map), and the map's settings are part of
    what a re-run compares."""
    from leovr.config import MapConfig
    from leovr.pipeline.batch import job_section, run_sequence, task_settings
    from leovr.pipeline.batch_manifest import BatchItem

    item = BatchItem("drive0", drives / "drive0")
    section = job_section(LeovrConfig.model_validate({"refine": {"end": 4}}), "refine", item)
    with process_threads():
        state = run_sequence(item, "refine", section, tmp_path / "drive0", map_section=MapConfig().model_dump())
    assert state["status"] == "done", state
    assert json.loads((tmp_path / "drive0" / "map" / "map.json").read_text())["frames"] == 4
    assert task_settings("refine", section, item.path, MapConfig().model_dump()) != task_settings(
        "refine", section, item.path
    )
