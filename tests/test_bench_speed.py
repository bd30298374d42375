"""`leovr bench speed` on a short rendered drive (no KITTI): the stage statistics come from the run's
own per-frame series, and speed is reported with the same run's accuracy."""

from __future__ import annotations

import json

import pytest

from leovr.bench.speed import growth, run_speed_bench
from leovr.bench.config import BenchSpeedConfig
from leovr.pipeline.refine_outputs import TIMED, timing_record


def test_growth_is_one_for_a_flat_series_and_grows_with_a_rising_one():
    assert growth([10.0] * 40) == pytest.approx(1.0)
    assert growth(list(range(1, 41))) == pytest.approx(35.5 / 15.5, rel=0.05)  # last quarter over second
    assert growth([1.0] * 5) is None  # too short to say


def test_timing_record_reads_runs_from_before_the_output_stage_was_timed():
    rec = timing_record({0: [10.0, 20.0, 30.0], 1: [10.0, 20.0, 30.0, 5.0]}, [0, 1])  # resumed: old and new frames
    assert rec["series"]["output_ms"] == [0.0, 5.0] and rec["series"]["total_ms"] == [60.0, 65.0]
    assert rec["graph_ms"] == 30.0 and rec["frames_timed"] == 2
    assert rec["series"]["wall_ms"] == [None, None] and "wall_ms" not in rec["stats"]  # not recorded then
    new = timing_record({0: [10.0, 20.0, 30.0, 5.0, 50.0, 80.0], 1: [12.0, 20.0, 30.0, 5.0, 52.0, 90.0]}, [0, 1])
    assert new["stats"]["wall_ms"]["median"] == 51.0 and new["stats"]["total_ms"]["max"] == 67.0
    assert new["stats"]["cpu_ms"]["median"] == 85.0 and rec["series"]["cpu_ms"] == [None, None]


@pytest.mark.slow
def test_bench_speed_contract(tmp_path):
    cfg = BenchSpeedConfig(quick_frames=8, clips=[])
    doc = run_speed_bench(tmp_path / "s.json", cfg, quick=True, progress=False)
    assert json.loads((tmp_path / "s.json").read_text())["benchmark"] == "speed"
    assert list(doc["results"]) == ["synthetic_mid40_448x256"]  # no real clip given
    r = doc["results"]["synthetic_mid40_448x256"]
    assert r["frames"] == 8 and (r["width"], r["height"]) == (448, 256)
    ms = r["ms_per_frame"]
    assert set(ms) == {"generator_ms", "frontend_ms", "graph_ms", "output_ms", "total_ms", "wall_ms", "cpu_ms"}
    for stage in (*TIMED, "total_ms"):
        assert 0 < ms[stage]["median"] <= ms[stage]["p95"] <= ms[stage]["max"]
    # the sum's median is at least the largest stage median and at most the sum of the stage maxima
    assert max(ms[s]["median"] for s in TIMED) <= ms["total_ms"]["median"] + 0.01
    assert ms["total_ms"]["max"] <= sum(ms[s]["max"] for s in TIMED) + 0.01
    assert r["fps_stages"] == pytest.approx(1000.0 / ms["total_ms"]["median"], rel=1e-2)
    # the generator of the next frame runs beside the graph: a frame's wall time is under the stage sum, and at
    # least the graph's and front end's, which stay sequential
    assert ms["graph_ms"]["median"] + ms["frontend_ms"]["median"] <= ms["wall_ms"]["median"] + 1.0
    assert ms["wall_ms"]["median"] < ms["total_ms"]["median"]
    assert 0 < r["fps_wall"] < r["fps_frame_wall"]  # the run's clock also reads the first frame, scores and writes
    assert r["ipbasic_ms_per_frame"] > 0 and r["total_over_ipbasic"] > 1
    assert r["mae_m"]["refined"] > 0 and r["ate_m"]["leovr"] >= 0
    # CPU time: every thread's (the generator runs beside the graph); under load the wall time grows, the CPU time not
    assert 0.3 * ms["wall_ms"]["median"] < ms["cpu_ms"]["median"] < 2.5 * ms["wall_ms"]["median"]
    assert set(doc["targets_met"]) == {"synthetic_mid40_448x256_wall_median_ms<=250"} | {
        f"synthetic_mid40_448x256_{s}_p95/median<=1.5" for s in (*TIMED, "total_ms", "wall_ms")
    }
