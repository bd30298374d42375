"""Configuration models (pydantic) and YAML loading. Every CLI option can come from a config file;
options given on the command line override it."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from leovr.errors import ConfigError
from leovr.eval.depth_metrics import LEOVR_BINS
from leovr.lidar.cheap_sensor import parse_input


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class CompleteConfig(_Model):
    """`leovr complete`: classical completion of a cheap LiDAR input, scored on held-out points."""

    method: Literal["nearest", "ipbasic"] = "ipbasic"
    input: str = "mid40"
    seed: int = 0
    start: int = 0
    end: int | None = None
    step: int = 1
    bins: list[float] = list(LEOVR_BINS)
    parallax_window: int = 7
    parallax_rel: float = 0.15

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))

    @field_validator("step")
    @classmethod
    def _check_step(cls, v: int) -> int:
        if v < 1:
            raise ValueError("step must be at least 1")
        return v


class BenchBaselineConfig(_Model):
    """`leovr bench baseline`."""

    data: str | None = None  # KITTI raw clip; None = ../shared/data/kitti_raw
    inputs: list[str] = ["vlp16", "mid40"]
    methods: list[Literal["nearest", "ipbasic"]] = ["nearest", "ipbasic"]
    quick_step: int = 6  # --quick scores every 6th frame
    seed: int = 0


class DemoConfig(_Model):
    """`leovr demo`."""

    data: str | None = None  # sequence; None = the embedded default
    frames: int = 12
    input: str = "mid40"


class LeovrConfig(_Model):
    complete: CompleteConfig = CompleteConfig()
    bench_baseline: BenchBaselineConfig = BenchBaselineConfig()
    demo: DemoConfig = DemoConfig()


def load_config(path: str | Path | None = None) -> LeovrConfig:
    """Defaults, overlaid with a YAML file when given; unknown keys and bad values are errors."""
    if path is None:
        return LeovrConfig()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    try:
        return LeovrConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {exc}") from exc


def override(model: _Model, **options: Any) -> Any:
    """A copy of `model` with the options that were given (not None) applied and validated."""
    given = {k: v for k, v in options.items() if v is not None}
    try:
        return model.model_validate({**model.model_dump(), **given})
    except ValidationError as exc:
        raise ConfigError(str(exc)) from exc
