"""The generator on ONNX Runtime gives the torch network's depth and sigma (leovr.depth.runtime)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from leovr.config import CompleteConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.depth.inference import load_generator, predict_at_focal
from leovr.depth.network import DepthGenerator, GeneratorConfig
from leovr.depth.runtime import OnnxGenerator, for_inference
from leovr.paths import shipped_checkpoint
from leovr.pipeline.completion import prepare_sample
from leovr.sim.simulate import simulate


@pytest.mark.parametrize("size", [(448, 256, 260.0), (300, 180, 400.0)])  # native; resampled and padded
def test_onnx_runtime_matches_torch_on_a_rendered_frame(tmp_path: Path, size):
    w, h, f = size
    simulate(SimulateConfig(scenario="city_loop", lidar="mid40", frames=1, seed=3007, width=w, height=h, focal=f),
             tmp_path / "seq", progress=False)
    frame = open_sequence(tmp_path / "seq")[0]
    sample = prepare_sample(frame, CompleteConfig(method="generator", input="full"))
    model = load_generator(shipped_checkpoint())
    onnx = for_inference(model, "onnxruntime")
    assert isinstance(onnx, OnnxGenerator)
    d_t, s_t = predict_at_focal(model, frame.image, sample.sparse, f, 260.0)
    d_o, s_o = predict_at_focal(onnx, frame.image, sample.sparse, f, 260.0)
    assert d_o.shape == d_t.shape == (h, w) and np.isfinite(d_o).all()
    rel = np.abs(d_o - d_t) / d_t
    assert np.median(rel) < 1e-5 and rel.max() < 1e-4
    assert np.abs(s_o - s_t).max() < 1e-3
    assert np.abs(d_t - np.median(d_t)).mean() > 1.0  # a real depth map, not a constant


def test_absolute_networks_and_the_torch_setting_stay_on_torch():
    absolute = DepthGenerator(GeneratorConfig(output="absolute"))
    assert for_inference(absolute, "onnxruntime") is absolute
    shipped = load_generator(shipped_checkpoint())
    assert for_inference(shipped, "torch") is shipped
