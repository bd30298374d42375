"""`leovr bench refine` contract on a small configuration (rendered test sequences, no KITTI)."""

from __future__ import annotations

import pytest
import json

from leovr.bench.refine import run_refine_bench
from leovr.bench.config import BenchRefineConfig


@pytest.mark.slow
def test_bench_refine_contract(tmp_path):
    cfg = BenchRefineConfig(
        dataset=str(tmp_path / "data"),
        synthetic_lidars=["mid40"],
        kitti_raw_clips=[],
        windows=[2, 3],
        kitti_odometry=str(tmp_path / "absent"),
        quick_frames=4,
    )
    doc = run_refine_bench(tmp_path / "r.json", cfg, quick=True, progress=False)
    assert json.loads((tmp_path / "r.json").read_text())["benchmark"] == "refine"
    res = doc["results"]["synthetic_mid40"]
    # Mid-40: earlier scans in the generator input, and the fills of the same frames' returns beside it
    assert set(res) == {
        "nearest",
        "ipbasic",
        "nearest_accumulated",
        "ipbasic_accumulated",
        "generator",
        "generator_frame",
        "refined",
    }
    for r in res.values():
        assert r["n"] > 3 * 4 * 100_000 and set(r["bins"]) and len(r["per_sequence_mae_m"]) == 3  # 3 scenarios
    # a cone LiDAR: the graph's depth beats the nearest fill and its several-frame version, the generator's own scan
    assert res["refined"]["mae_m"] < 0.5 * res["nearest"]["mae_m"]
    assert res["refined"]["mae_m"] < res["nearest_accumulated"]["mae_m"]
    traj = doc["trajectory"]["synthetic_mid40"]
    assert traj["leovr"]["ate_m"] > 0 and traj["kiss_icp"]["ate_m"] > 0
    assert set(doc["timing"]) == {"generator_ms", "frontend_ms", "graph_ms", "output_ms"}
    assert set(doc["window_ablation"]["results"]) == {"2", "3"}
