"""The generator's ONNX graph in 8-bit integers (ONNX Runtime static quantisation, QDQ format).

Static quantisation needs each activation's range. They are measured once on frames the user never
scores (`calibrate_ranges`: simulator training frames for the shipped network, `tools/calibrate_int8.py`;
the training frames for `leovr train --mode selfsup`) and stored in the checkpoint (`int8_ranges`). The
ranges do not depend on the image size, so every input size the runtime exports is quantised from them
(`quantized_model`) in about 2 s, once per size.

Kept in floating point: the LiDAR branch (sparse convolutions normalised by their mask, on depths in
metres: 8 bits would step by decimetres), the stems that read the inputs, the full-resolution refinement
and the output heads (log depth and sigma). The RGB encoder, the cross-attention and the decoders carry
most of the arithmetic and run in int8; weights per output channel.
"""

from __future__ import annotations

import io
import json
import logging
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

# node-name parts of the float islands (names as torch.onnx.export gives them to the network's modules)
FLOAT_PREFIXES = ("/lidar/",)
FLOAT_PARTS = ("/depth_head/", "/fusion_head/", "/sigma_head/", "/full/", "/stem/")
INPUTS = ("image", "sparse", "prior")


def export_fp32(parts: nn.Module, keys: tuple[str, ...], h: int, w: int, target: Path | io.BytesIO) -> None:
    """The network's `parts` (image, sparse, prior -> keys) as an ONNX model for H x W inputs, written to
    a file or a buffer."""
    args = (torch.zeros(1, 3, h, w), torch.zeros(1, 1, h, w), torch.ones(1, 1, h, w))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation and tracer notes
        torch.onnx.export(
            parts,
            args,
            target if isinstance(target, io.BytesIO) else str(target),
            dynamo=False,
            opset_version=17,
            input_names=list(INPUTS),
            output_names=list(keys),
            dynamic_axes={n: {0: "batch"} for n in (*INPUTS, *keys)},
        )


def _prepared(parts: nn.Module, keys: tuple[str, ...], h: int, w: int, folder: Path) -> Path:
    """Exported and pre-processed (shape inference, graph optimisation) for quantisation."""
    from onnxruntime.quantization.shape_inference import quant_pre_process

    raw, pre = folder / "fp32.onnx", folder / "fp32_pre.onnx"
    export_fp32(parts, keys, h, w, raw)
    quant_pre_process(str(raw), str(pre))
    return pre


def _float_nodes(path: Path) -> list[str]:
    import onnx

    names = [n.name for n in onnx.load(str(path)).graph.node]
    return [n for n in names if n.startswith(FLOAT_PREFIXES) or any(p in n for p in FLOAT_PARTS)]


def _quantize(pre: Path, out: Path, cache: Path, reader=None) -> None:
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static

    logger = logging.getLogger()  # the quantiser logs a warning per BatchNorm it leaves alone
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        quantize_static(
            str(pre),
            str(out),
            reader,
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            calibrate_method=CalibrationMethod.MinMax,
            nodes_to_exclude=_float_nodes(pre),
            calibration_cache_path=str(cache),
        )
    finally:
        logger.setLevel(level)


def calibrate_ranges(parts: nn.Module, keys: tuple[str, ...], feeds: list[dict[str, np.ndarray]]) -> dict:
    """Every quantised tensor's min / max over `feeds` (network inputs of one size, padded to 32):
    the JSON-able calibration table `quantized_model` reads."""
    from onnxruntime.quantization import CalibrationDataReader

    if not feeds:
        raise ValueError("int8 calibration needs at least one frame")
    h, w = feeds[0]["image"].shape[-2:]

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.it = iter(feeds)

        def get_next(self):
            return next(self.it, None)

    with tempfile.TemporaryDirectory(prefix="leovr-int8-") as tmp:
        folder = Path(tmp)
        cache = folder / "ranges.json"
        _quantize(_prepared(parts, keys, h, w, folder), folder / "int8.onnx", cache, Reader())
        return json.loads(cache.read_text())


def quantized_model(parts: nn.Module, keys: tuple[str, ...], ranges: dict, h: int, w: int) -> bytes:
    """The int8 ONNX model of `parts` for H x W inputs, quantised with the stored `ranges`."""
    with tempfile.TemporaryDirectory(prefix="leovr-int8-") as tmp:
        folder = Path(tmp)
        cache = folder / "ranges.json"
        cache.write_text(json.dumps(ranges))
        _quantize(_prepared(parts, keys, h, w, folder), folder / "int8.onnx", cache)
        return (folder / "int8.onnx").read_bytes()
