"""The depth generator on ONNX Runtime: same weights, same outputs, about 1.6x faster on this CPU; or in
8-bit integers from the checkpoint's calibration table (leovr.depth.quantize), faster again.

`torch.onnx.export` traces the network's `parts` (everything up to the combination with the prior) once
per input size, in memory; ONNX Runtime runs it, and torch combines the parts with the prior as before.
Only residual-mode networks (the shipped kind) are exported: an absolute-depth network fills its own
input with a data-dependent loop that a trace cannot hold, so it stays on torch.
"""

from __future__ import annotations

import hashlib
import io
import json
import warnings

import numpy as np
import torch
from torch import nn

from leovr.config import GeneratorRuntime as Runtime
from leovr.depth.network import DepthGenerator, prior_for
from leovr.depth.quantize import INPUTS, export_fp32


# exported (and quantised) models of this process, by weights, int8 table and input size: a benchmark or test
# that builds the same generator again skips the export (about 2 s in int8)
MAX_CACHED_GRAPHS = 8
_GRAPHS: dict[tuple[str, int, int], bytes] = {}


class PartsModule(nn.Module):
    """`DepthGenerator.parts` as a module with tuple outputs (ONNX export needs fixed outputs)."""

    def __init__(self, model: DepthGenerator, keys: tuple[str, ...]) -> None:
        super().__init__()
        self.model, self.keys = model, keys

    def forward(self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor) -> tuple[torch.Tensor, ...]:
        parts = self.model.parts(image, sparse, prior)
        return tuple(parts[k] for k in self.keys)


def part_keys(model: DepthGenerator) -> tuple[str, ...]:
    """The outputs of a residual-mode network's `parts` that inference combines with the prior."""
    return ("log_sigma", "log_residual") + (("prior_log_sigma",) if model.fusion_head is not None else ())


class _StandIn:
    """What inference asks of a residual-mode generator (`parts`, `combine`, call, `uses_prior`, `cfg`),
    with `parts` left to the subclass: the wrapped torch model combines the parts with the prior."""

    model: DepthGenerator
    cfg: object

    @property
    def uses_prior(self) -> bool:
        return True

    def parts(self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def combine(self, parts: dict[str, torch.Tensor], prior: torch.Tensor | None, sparse: torch.Tensor) -> torch.Tensor:
        return self.model.combine(parts, prior, sparse)

    def __call__(
        self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        if prior is None:
            prior = prior_for(sparse)
        parts = self.parts(image, sparse, prior)
        return self.combine(parts, prior, sparse), parts["log_sigma"]


class OnnxGenerator(_StandIn):
    """Stands in for a `DepthGenerator` at inference (`parts`, `combine`, call, `uses_prior`, `cfg`):
    `parts` runs on ONNX Runtime with as many threads as torch has (`torch.get_num_threads()`), in 8-bit
    integers when `int8_ranges` (the checkpoint's calibration table, leovr.depth.quantize) are given."""

    def __init__(self, model: DepthGenerator, int8_ranges: dict | None = None) -> None:
        if not model.uses_prior:
            raise ValueError("only residual-mode generators run on ONNX Runtime")
        import onnx  # noqa: F401  (the exporter needs it; fail here, not at the first frame)
        import onnxruntime  # noqa: F401

        self.model = model.eval()
        self.cfg = model.cfg
        self.keys = part_keys(model)
        self.int8_ranges = int8_ranges
        self._sessions: dict[tuple[int, int], object] = {}
        self._key: str | None = None

    def _session(self, h: int, w: int):
        import onnxruntime as ort

        if (h, w) not in self._sessions:
            key = (self._digest(), h, w)
            graph = _GRAPHS.get(key)
            if graph is None:
                graph = self._export(h, w)
                _GRAPHS[key] = graph
                while len(_GRAPHS) > MAX_CACHED_GRAPHS:
                    _GRAPHS.pop(next(iter(_GRAPHS)))
            opts = ort.SessionOptions()
            opts.intra_op_num_threads = max(1, torch.get_num_threads())
            opts.inter_op_num_threads = 1
            # no busy-waiting between frames: spinning workers would take the cores the front end and graph use
            opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
            self._sessions[(h, w)] = ort.InferenceSession(graph, opts, providers=["CPUExecutionProvider"])
        return self._sessions[(h, w)]

    def _export(self, h: int, w: int) -> bytes:
        """The ONNX model for H x W inputs: exported, and quantised when the runtime is int8 (~2 s)."""
        if self.int8_ranges is not None:
            from leovr.depth.quantize import quantized_model

            return quantized_model(PartsModule(self.model, self.keys), self.keys, self.int8_ranges, h, w)
        buf = io.BytesIO()
        export_fp32(PartsModule(self.model, self.keys), self.keys, h, w, buf)
        return buf.getvalue()

    def _digest(self) -> str:
        """What the exported model depends on: the weights, the network description and the int8 table."""
        if self._key is None:
            h = hashlib.sha1(repr(sorted(self.cfg.__dict__.items())).encode())
            for name, t in self.model.state_dict().items():
                h.update(name.encode())
                h.update(t.detach().contiguous().cpu().numpy().tobytes())
            h.update(json.dumps(self.int8_ranges, sort_keys=True).encode())
            self._key = h.hexdigest()
        return self._key

    def parts(
        self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        h, w = image.shape[-2:]
        if h % 32 or w % 32:
            raise ValueError(f"image size {w}x{h} must be a multiple of 32 in both directions")
        if prior is None:
            raise ValueError("a residual-mode generator needs the classical prior (prior_for)")
        feed = {
            "image": image.detach().float().contiguous().numpy(),
            "sparse": sparse.detach().float().contiguous().numpy(),
            "prior": prior.detach().float().contiguous().numpy(),
        }
        out = self._session(h, w).run(list(self.keys), feed)
        return {k: torch.from_numpy(v) for k, v in zip(self.keys, out)}


class InputRecorder(_StandIn):
    """Stands in for a residual-mode generator at inference (torch) and keeps every network input it
    is given (padded image, sparse depth and prior): the frames an int8 calibration measures."""

    def __init__(self, model: DepthGenerator) -> None:
        self.model, self.cfg = model.eval(), model.cfg
        self.feeds: list[dict[str, np.ndarray]] = []

    def parts(self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor) -> dict[str, torch.Tensor]:
        self.feeds.append({k: v.detach().float().numpy().copy() for k, v in zip(INPUTS, (image, sparse, prior))})
        return self.model.parts(image, sparse, prior)


def calibrate_generator(model: DepthGenerator, feeds: list[dict[str, np.ndarray]]) -> dict:
    """The int8 calibration table of `model` from network inputs (`InputRecorder.feeds`); inputs of
    another size than the most common one are left out (one export measures them)."""
    from collections import Counter

    from leovr.depth.quantize import calibrate_ranges

    if not feeds:
        raise ValueError("int8 calibration needs at least one frame")
    size = Counter(f["image"].shape[-2:] for f in feeds).most_common(1)[0][0]
    keys = part_keys(model)
    return calibrate_ranges(PartsModule(model.eval(), keys), keys, [f for f in feeds if f["image"].shape[-2:] == size])


def for_inference(model: DepthGenerator, runtime: Runtime = "onnxruntime") -> DepthGenerator | OnnxGenerator:
    """The model to run frames through: ONNX Runtime when asked and possible (a residual-mode network),
    else the torch model (with a warning when ONNX Runtime was asked for but is not installed).
    `onnxruntime_int8` needs the checkpoint's calibration table (`model.int8_ranges`, set by
    `load_generator`); without one it warns and runs in floating point."""
    if runtime == "torch" or not model.uses_prior:
        return model.eval()
    ranges = None
    if runtime == "onnxruntime_int8":
        ranges = getattr(model, "int8_ranges", None)
        if ranges is None:
            warnings.warn(
                "the checkpoint has no int8 calibration table (tools/calibrate_int8.py writes one); "
                "the generator runs in floating point",
                stacklevel=2,
            )
    try:
        return OnnxGenerator(model, ranges)
    except ImportError as exc:
        warnings.warn(f"ONNX Runtime is not available ({exc}); the generator runs on torch", stacklevel=2)
        return model.eval()
