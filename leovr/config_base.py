"""The configuration models' common base: strict pydantic models, and what every depth job shares."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from leovr.eval.depth_metrics import LEOVR_BINS
from leovr.lidar.cheap_sensor import parse_input

GeneratorRuntime = Literal["torch", "onnxruntime", "onnxruntime_int8"]  # leovr.depth.runtime.for_inference


class _Model(BaseModel):
    # no NaN or infinity in a setting (the distance bins' open end is the one exception: `bins`)
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


def top_level_seed() -> Any:
    """A job's seed field: set once, at the top level of a config file (`LeovrConfig.seed`), which fills every job's;
    a job carries its copy so that the settings a run saves say everything it drew with. A section may not set its
    own, and the reference (docs/config.md) lists the top-level one only. Set `LeovrConfig.seed` by assignment or
    validation (`override`): `model_copy(update=...)` skips the validators and leaves the sections' copies behind."""
    return Field(0, ge=0, json_schema_extra={"top_level": True})


class FrameSelection(_Model):
    """What depth jobs share: the generator, the cheap LiDAR input, the frames and how they are scored."""

    checkpoint: str | None = None  # generator weights (.pt); None = the shipped checkpoint
    # generator run at this focal length (px, its training camera); None = native
    generator_focal_px: float | None = 260.0
    # onnxruntime_int8: the network in 8-bit integers from the checkpoint's calibration table (leovr.depth.quantize;
    # a checkpoint without one runs in floating point, with a warning); onnxruntime: floating point, torch's outputs
    generator_runtime: GeneratorRuntime = "onnxruntime_int8"
    # the classical prior at depth edges (generator and `interp`): the side the image puts a pixel on, or the nearest
    # return
    prior_edges: Literal["image", "nearest"] = "image"
    input: str = "mid40"  # cheap LiDAR input simulated from the sequence's scan (full, vlp16, mid40, ratio:R)
    seed: int = top_level_seed()  # the cheap input's ratio:R draws, the graph's samples of returns and pixels
    start: int = Field(0, ge=0)  # first frame (index into the sequence)
    end: int | None = Field(None, ge=1)  # frame index to stop before; None = the last frame
    step: int = Field(1, ge=1)  # every n-th frame
    # ground-truth distance bins (m) the depth error is also reported in (increasing; the last may be .inf)
    bins: list[Annotated[float, Field(allow_inf_nan=True)]] = list(LEOVR_BINS)

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))

    @field_validator("bins")
    @classmethod
    def _check_bins(cls, v: list[float]) -> list[float]:
        if len(v) < 2 or any(b != b for b in v) or v[0] < 0 or any(b >= a for a, b in zip(v[1:], v)):
            raise ValueError(f"bins must be at least two increasing distances from 0 or more, not {v}")
        return v

    @field_validator("step")
    @classmethod
    def _check_step(cls, v: int) -> int:
        if v < 1:
            raise ValueError("step must be at least 1")
        return v
