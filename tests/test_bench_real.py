"""`leovr bench real` contract on a small configuration of the shared KITTI raw clip."""

from __future__ import annotations

import json

from leovr.bench.real import METHODS, run_real_bench
from leovr.config import BenchRealConfig
from tests.conftest import KITTI_RAW, needs_shared


@needs_shared
def test_bench_real_contract(tmp_path):
    cfg = BenchRealConfig(kitti_raw=str(KITTI_RAW), inputs=["vlp16"], quick_frames=5, quick_train_frames=3)
    doc = run_real_bench(tmp_path / "real.json", cfg, quick=True, progress=False)
    assert json.loads((tmp_path / "real.json").read_text())["benchmark"] == "real"
    assert set(doc["results"]) == {"inductive_vlp16", "transductive_vlp16"}
    ind, trans = doc["results"]["inductive_vlp16"], doc["results"]["transductive_vlp16"]
    # VLP-16-like input spins: no earlier scans join the generator's, so no separate single-frame row
    assert set(ind) == set(METHODS) - {"generator_frame"} == {"nearest", "ipbasic", "interp", "generator", "refined",
                                                              "adapted", "adapted_refined"}
    for r in (ind, trans):
        ns = {m: v["n"] for m, v in r.items()}
        assert len(set(ns.values())) == 1 and min(ns.values()) > 1000  # every method on the same pixels
        for v in r.values():
            assert {"mae_m", "rmse_m", "absrel", "delta1", "n", "bins"} <= set(v) and v["mae_m"] > 0
    assert trans["nearest"]["n"] > ind["nearest"]["n"]  # 5 frames scored vs 2
    assert set(doc["adapt_minutes"]) == {"inductive_vlp16", "transductive_vlp16"}
    assert "held-out LiDAR points" in doc["ground_truth"]
