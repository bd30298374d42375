"""`leovr bench depth`: contract keys, the generator against classical fills, sigma ranking errors;
and the focal-length resampling the generator runs behind."""

from __future__ import annotations

import pytest
import json

import numpy as np

from leovr.bench.depth import run_depth_bench
from leovr.bench.config import BenchDepthConfig
from leovr.depth.inference import (
    load_generator,
    predict,
    predict_at_focal,
    rescale_sparse,
)
from leovr.paths import shipped_checkpoint


def test_rescale_sparse_keeps_the_nearest_return_per_pixel():
    sp = np.zeros((10, 20), np.float32)
    sp[4, 5], sp[4, 6], sp[9, 19] = 5.0, 3.0, 8.0  # columns 5 and 6 both round to 3 after halving
    out = rescale_sparse(sp, 0.5, (5, 10))
    assert out[2, 3] == 3.0 and out[4, 9] == 8.0  # 19 * 0.5 rounds to 10, clipped to the last column
    assert np.count_nonzero(out) == 2


def test_predict_at_focal_returns_frame_size_and_matches_native_at_same_focal():
    model = load_generator(shipped_checkpoint())
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (120, 400, 3), np.uint8)
    sp = np.where(rng.random((120, 400)) < 0.05, rng.uniform(3, 40, (120, 400)), 0).astype(np.float32)
    d, s = predict_at_focal(model, img, sp, focal_px=520.0, model_focal_px=260.0)
    assert d.shape == s.shape == (120, 400) and np.all(d > 0)
    native = predict(model, img, sp)[0]
    same = predict_at_focal(model, img, sp, focal_px=260.0, model_focal_px=260.0)[0]
    assert np.array_equal(same, native) and not np.allclose(d, native)


@pytest.mark.slow
def test_bench_depth_quick_synthetic(tmp_path):
    cfg = BenchDepthConfig(dataset=str(tmp_path / "data"), synthetic_lidars=["mid40"], kitti_inputs=[])
    doc = run_depth_bench(tmp_path / "b.json", cfg, quick=True, progress=False)
    assert json.loads((tmp_path / "b.json").read_text())["results"] == doc["results"]
    res = doc["results"]["synthetic_mid40"]
    assert set(res) == {"nearest", "ipbasic", "interp", "generator"}
    for r in res.values():
        assert r["mae_m"] > 0 and r["n"] > 10_000 and set(r["by_light"]) == {"day", "night"}
    # outside the Mid-40 cone the classical fills have nothing to go on; the generator uses the image
    assert res["generator"]["mae_m"] < 0.7 * res["ipbasic"]["mae_m"]
    assert res["generator"]["uncertainty"]["spearman_error_sigma"] > 0.3
    assert res["generator"]["ms_per_frame"] > 0 and "generator_mae_vs_ipbasic" in doc["summary"]["synthetic_mid40"]
