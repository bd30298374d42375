"""The depth generator on ONNX Runtime: same weights, same outputs, about 1.6x faster on this CPU.

`torch.onnx.export` traces the network's `parts` (everything up to the combination with the prior) once
per input size, in memory; ONNX Runtime runs it, and torch combines the parts with the prior as before.
Only residual-mode networks (the shipped kind) are exported: an absolute-depth network fills its own
input with a data-dependent loop that a trace cannot hold, so it stays on torch.
"""

from __future__ import annotations

import io
import warnings
from typing import Literal

import torch
from torch import nn

from leovr.depth.network import DepthGenerator, prior_for

Runtime = Literal["torch", "onnxruntime"]


class _Parts(nn.Module):
    """`DepthGenerator.parts` as a module with tuple outputs (ONNX export needs fixed outputs)."""

    def __init__(self, model: DepthGenerator, keys: tuple[str, ...]) -> None:
        super().__init__()
        self.model, self.keys = model, keys

    def forward(self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor) -> tuple[torch.Tensor, ...]:
        parts = self.model.parts(image, sparse, prior)
        return tuple(parts[k] for k in self.keys)


class OnnxGenerator:
    """Stands in for a `DepthGenerator` at inference (`parts`, `combine`, call, `uses_prior`, `cfg`):
    `parts` runs on ONNX Runtime with as many threads as torch has (`torch.get_num_threads()`)."""

    def __init__(self, model: DepthGenerator) -> None:
        if not model.uses_prior:
            raise ValueError("only residual-mode generators run on ONNX Runtime")
        import onnx  # noqa: F401  (the exporter needs it; fail here, not at the first frame)
        import onnxruntime  # noqa: F401

        self.model = model.eval()
        self.cfg = model.cfg
        self.keys = ("log_sigma", "log_residual") + (("prior_log_sigma",) if model.fusion_head is not None else ())
        self._sessions: dict[tuple[int, int], object] = {}

    @property
    def uses_prior(self) -> bool:
        return True

    def _session(self, h: int, w: int):
        import onnxruntime as ort

        if (h, w) not in self._sessions:
            buf = io.BytesIO()
            args = (torch.zeros(1, 3, h, w), torch.zeros(1, 1, h, w), torch.ones(1, 1, h, w))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation and tracer notes
                torch.onnx.export(_Parts(self.model, self.keys), args, buf, dynamo=False, opset_version=17,
                                  input_names=["image", "sparse", "prior"], output_names=list(self.keys),
                                  dynamic_axes={n: {0: "batch"} for n in ("image", "sparse", "prior", *self.keys)})
            opts = ort.SessionOptions()
            opts.intra_op_num_threads = max(1, torch.get_num_threads())
            opts.inter_op_num_threads = 1
            # no busy-waiting between frames: spinning workers would take the cores the front end and graph use
            opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
            self._sessions[(h, w)] = ort.InferenceSession(buf.getvalue(), opts, providers=["CPUExecutionProvider"])
        return self._sessions[(h, w)]

    def parts(self, image: torch.Tensor, sparse: torch.Tensor, prior: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        h, w = image.shape[-2:]
        if h % 32 or w % 32:
            raise ValueError(f"image size {w}x{h} must be a multiple of 32 in both directions")
        if prior is None:
            raise ValueError("a residual-mode generator needs the classical prior (prior_for)")
        feed = {"image": image.detach().float().contiguous().numpy(),
                "sparse": sparse.detach().float().contiguous().numpy(),
                "prior": prior.detach().float().contiguous().numpy()}
        out = self._session(h, w).run(list(self.keys), feed)
        return {k: torch.from_numpy(v) for k, v in zip(self.keys, out)}

    def combine(self, parts: dict[str, torch.Tensor], prior: torch.Tensor | None, sparse: torch.Tensor) -> torch.Tensor:
        return self.model.combine(parts, prior, sparse)

    def __call__(self, image: torch.Tensor, sparse: torch.Tensor,
                 prior: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        if prior is None:
            prior = prior_for(sparse)
        parts = self.parts(image, sparse, prior)
        return self.combine(parts, prior, sparse), parts["log_sigma"]


def for_inference(model: DepthGenerator, runtime: Runtime = "onnxruntime") -> DepthGenerator | OnnxGenerator:
    """The model to run frames through: ONNX Runtime when asked and possible (a residual-mode network),
    else the torch model (with a warning when ONNX Runtime was asked for but is not installed)."""
    if runtime == "torch" or not model.uses_prior:
        return model.eval()
    try:
        return OnnxGenerator(model)
    except ImportError as exc:
        warnings.warn(f"ONNX Runtime is not available ({exc}); the generator runs on torch", stacklevel=2)
        return model.eval()
