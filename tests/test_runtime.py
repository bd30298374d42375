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


def rendered_frame(tmp_path: Path, scenario: str, lidar: str, seed: int, size: tuple[int, int, float]):
    """One rendered frame of `size` (width, height, focal) and its own-scan sample."""
    w, h, f = size
    simulate(
        SimulateConfig(scenario=scenario, lidar=lidar, frames=1, seed=seed, width=w, height=h, focal=f),
        tmp_path / "seq",
        progress=False,
    )
    frame = open_sequence(tmp_path / "seq")[0]
    return frame, prepare_sample(frame, CompleteConfig(method="generator", input="full"))


@pytest.mark.parametrize("size", [(448, 256, 260.0), (300, 180, 400.0)])  # native; resampled and padded
def test_onnx_runtime_matches_torch_on_a_rendered_frame(tmp_path: Path, size):
    w, h, f = size
    frame, sample = rendered_frame(tmp_path, "city_loop", "mid40", 3007, size)
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


@pytest.mark.slow
@pytest.mark.parametrize("size", [(448, 256, 260.0), (300, 180, 400.0)])  # calibrated size; another size, padded
def test_int8_runtime_keeps_the_depth_of_the_floating_point_network(tmp_path: Path, size):
    """The shipped checkpoint's int8 table (measured at 448 x 256 on training frames) quantises the network
    at any input size; its depth stays within a few per cent of floating point and as near the truth."""
    f = size[2]
    frame, sample = rendered_frame(tmp_path, "dynamic", "vlp16", 3011, size)
    model = load_generator(shipped_checkpoint())
    assert model.int8_ranges is not None
    fp32, int8 = for_inference(model, "onnxruntime"), for_inference(model, "onnxruntime_int8")
    assert fp32.int8_ranges is None and int8.int8_ranges is model.int8_ranges
    d_f, s_f = predict_at_focal(fp32, frame.image, sample.sparse, f, 260.0)
    d_q, s_q = predict_at_focal(int8, frame.image, sample.sparse, f, 260.0)
    rel = np.abs(d_q - d_f) / d_f
    assert 1e-4 < np.median(rel) < 0.03  # quantised (not the float graph) but close
    gt = sample.gt > 0
    mae_f, mae_q = (np.abs(d - sample.gt)[gt].mean() for d in (d_f, d_q))
    assert mae_q < 1.05 * mae_f
    assert np.isfinite(s_q).all() and np.abs(s_q - s_f).mean() < 0.1


def test_int8_without_a_calibration_table_warns_and_runs_in_floating_point(tmp_path: Path):
    model = load_generator(shipped_checkpoint())
    model.int8_ranges = None  # as a checkpoint trained before the int8 runtime
    with pytest.warns(UserWarning, match="no int8 calibration table"):
        gen = for_inference(model, "onnxruntime_int8")
    assert isinstance(gen, OnnxGenerator) and gen.int8_ranges is None


def test_a_broken_int8_table_names_the_checkpoint(tmp_path: Path):
    import torch

    from leovr.errors import DataError

    state = torch.load(shipped_checkpoint(), map_location="cpu", weights_only=False)
    state["int8_ranges"] = [1, 2, 3]
    torch.save(state, tmp_path / "g.pt")
    with pytest.raises(DataError, match=r"g\.pt: its int8 calibration table"):
        load_generator(tmp_path / "g.pt")


def test_an_exported_model_is_reused_only_for_the_same_weights_and_table():
    import torch

    model = load_generator(shipped_checkpoint())
    a, b = (
        for_inference(model, "onnxruntime_int8"),
        for_inference(load_generator(shipped_checkpoint()), "onnxruntime_int8"),
    )
    assert a._digest() == b._digest()  # a second build of the same checkpoint skips the ~2 s export
    assert for_inference(model, "onnxruntime")._digest() != a._digest()  # no table: the floating-point graph
    other = load_generator(shipped_checkpoint())
    with torch.no_grad():
        next(other.parameters()).add_(1e-3)
    assert for_inference(other, "onnxruntime_int8")._digest() != a._digest()
