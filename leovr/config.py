"""Configuration models (pydantic) and YAML loading. Every CLI option can come from a config file;
options given on the command line override it."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, TypeVar

from pydantic import Field, ValidationError, field_validator, model_serializer, model_validator

from leovr.config_base import FrameSelection, GeneratorRuntime, _Model, top_level_seed  # noqa: F401  (re-exported)
from leovr.errors import ConfigError
from leovr.lidar.cheap_sensor import parse_input
from leovr.refine_config import (  # noqa: F401  (re-exported: leovr.config names every model)
    AccumulationConfig,
    CameraOnlyConfig,
    CameraOnlyGraphConfig,
    FrontEndConfig,
    GraphConfig,
    LoopConfig,
    MotionStereoConfig,
    PhotometricConfig,
    RefineConfig,
)

M = TypeVar("M", bound=_Model)

Scenario = Literal["city_loop", "straight", "dynamic", "traffic"]  # leovr.sim.world.SCENARIOS


class CompleteConfig(FrameSelection):
    """`leovr complete`: classical completion of a cheap LiDAR input, scored on held-out points."""

    method: Literal["nearest", "ipbasic", "interp", "generator"] = "ipbasic"  # completion method


class SimulateConfig(_Model):
    """`leovr simulate`: one rendered sequence of the procedural world."""

    scenario: Scenario = "city_loop"  # the procedural world's route and traffic
    lidar: Literal["vlp16", "hdl64", "mid40"] = "mid40"  # simulated LiDAR
    frames: int = Field(20, ge=1)  # frames rendered
    seed: int = top_level_seed()  # the world and the drive
    light: Literal["day", "dusk", "night"] = "day"  # lighting of the rendered images
    speed_kmh: float = Field(30.0, ge=0.0)  # driving speed (km/h)
    rate_hz: float = Field(10.0, gt=0.0)  # frame rate (Hz)
    width: int = Field(448, ge=16)  # image width (px)
    height: int = Field(256, ge=16)  # image height (px)
    focal: float = Field(260.0, gt=0.0)  # camera focal length (px)


class DemoConfig(_Model):
    """`leovr demo`: by default a generated Mid-40 sequence (the embedded default)."""

    data: str | None = None  # a recorded sequence instead of the generated one
    frames: int = Field(12, ge=1)  # frames generated and refined
    scenario: Scenario = "city_loop"  # generated sequence's scenario
    lidar: Literal["vlp16", "hdl64", "mid40"] = "mid40"  # generated sequence's LiDAR
    seed: int = top_level_seed()  # the generated sequence
    input: str | None = None  # None: all of the generated scan, or mid40 on a recorded dense scan


class OptimiserSettings(_Model):
    """How both trainers optimise (`leovr train --mode supervised | selfsup`): Adam, its learning rate stepped
    down every few epochs (LeoVR Sec. V-A defaults)."""

    epochs: int = Field(24, ge=1)  # training epochs
    batch_size: int = Field(8, ge=1)  # frames per batch
    lr: float = Field(1e-4, gt=0)  # learning rate
    lr_step_epochs: int = Field(6, ge=1)  # learning rate multiplied by lr_gamma every this many epochs
    lr_gamma: float = Field(0.5, gt=0, le=1)  # ... by this factor
    seed: int = top_level_seed()  # sampling and initialisation


class NetworkSettings(_Model):
    """The depth generator both trainers build (leovr.depth.network.GeneratorConfig), and the weights it starts
    from."""

    # LiDAR branch: SLIM partial convolutions | pre-interpolated input
    lidar_encoder: Literal["partial", "interp"] = "partial"
    cross_attention: bool = True  # image-LiDAR cross attention at the encoders' deepest stage
    # what the decoder predicts (leovr.depth.network); fusion: a residual over the classical prior with an
    # uncertainty-driven blend, so the untrained network returns the prior (decision 0017)
    output: Literal["absolute", "residual", "fusion"] = "fusion"
    channels: list[int] = [16, 32, 64, 128, 128]  # encoder channels: stem, then each stage (stride 2 each)
    blocks: list[int] = [3, 4, 6, 3]  # ResNet blocks per encoder stage
    init_checkpoint: str | None = None  # start from these weights (fine-tuning) instead of random ones; same network


class TrainConfig(NetworkSettings, OptimiserSettings):
    """`leovr train --mode supervised`: the depth generator on simulator splits (LeoVR Sec. V-A defaults)."""

    dataset: str | None = None  # folder with manifest.json; None: the cached recipe below
    recipe: str = "default"  # dataset recipe (tools/make_dataset.py --recipe)
    sigma_epochs: int = Field(2, ge=0)  # second phase: uncertainty head only, depth path frozen
    loss: Literal["l1", "l2"] = "l1"  # depth loss, masked on valid ground truth
    smoothness: float = Field(0.0, ge=0)  # weight of edge-aware smoothness (optional)
    max_frames: int | None = Field(None, ge=1)  # cap on training frames (quick runs)
    # the residual networks' classical prior at depth edges: the image's side (as at inference) or the nearest return
    prior_edges: Literal["image", "nearest"] = "image"


class SelfSupConfig(NetworkSettings, OptimiserSettings):
    """`leovr train --mode selfsup`: cold-start self-supervised training (LeoVR Sec. IV, V-A). No ground
    truth is read: poses, landmarks and refined depth come from the graph on the raw sequences."""

    init_fraction: float = Field(0.75, ge=0, le=1)  # initialisation stage: the first 3/4 of the epochs (18 of 24)
    refresh_every: int = Field(2, ge=1)  # refinement stage: poses, masks and supervision renewed every 2 epochs
    weight_feature: float = Field(0.4, ge=0)  # lambda_f, eq. 22
    weight_refined: float = Field(0.1, ge=0)  # lambda_r
    weight_smooth: float = Field(0.2, ge=0)  # lambda_s
    # sparse depth reconstruction |log D - log z| at the LiDAR input's returns (0: off;
    # docs/decisions/0011-tuned-settings.md)
    weight_sparse: float = Field(0.0, ge=0)
    # masked LiDAR: part of each frame's input hidden, |log D - log z| at the hidden returns (selfsup.masked_lidar;
    # docs/decisions/0017-selfsup-starts-at-the-prior.md)
    weight_masked: float = Field(1.0, ge=0)
    # with init_checkpoint: mean |log D - log D0| over every pixel, D0 the starting network's depth on the same
    # input, so that fine-tuning corrects the checkpoint without drifting from it where nothing says it is wrong
    weight_anchor: float = Field(5.0, ge=0)
    # L_f and L_r: |log D - log D*| (default) or the paper's squared metres
    target_loss: Literal["log_l1", "l2"] = "log_l1"
    flow_mask: bool = True  # eq. 19 motion-optical-flow mask on the photometric loss
    rigid_mask: bool = True  # also drop pixels whose flow disagrees with the rigid flow of the graph's pose and depth
    depth_mask: bool = False  # drop pixels whose depth, moved into the neighbour, disagrees with the neighbour's depth
    # monodepth2: per-pixel minimum over the neighbours, pixels that match better unwarped dropped
    auto_mask: bool = True
    # Gaussian NLL of the uncertainty head at the LiDAR-backed landmarks (0: head untrained)
    weight_nll: float = Field(0.1, ge=0)
    input: str = "full"  # LiDAR input of the generator and the graph (full, vlp16, mid40, ratio:R)
    # frames resampled to this focal length (px; the generator's camera); None = native
    train_focal_px: float | None = 260.0
    max_frames: int | None = Field(None, ge=1)  # first frames of each sequence only (None = all)
    loop_closure: bool = True  # pose quality assurance (Sec. IV-B) in every graph pass

    @field_validator("input")
    @classmethod
    def _check_input(cls, v: str) -> str:
        return str(parse_input(v))


class MapConfig(_Model):
    """`leovr map`: a refine run's depth, images and poses fused into a TSDF map (mesh and points)."""

    # voxel edge (m): finer maps are more accurate and more complete, at the cost of time and memory
    # (docs/decisions/0011-tuned-settings.md)
    voxel_m: float = Field(0.05, gt=0.0)
    max_depth_m: float = Field(40.0, gt=0.0)  # pixels deeper than this are left out
    # pixels whose predicted uncertainty (sigma/ of the run) exceeds this fraction of their depth are left out;
    # None keeps them all: no threshold made a real map better (docs/decisions/0011-tuned-settings.md)
    sigma_max: float | None = Field(None, gt=0.0)
    # pixels whose 3 x 3 neighbourhood spans more than a factor 1 + edge_jump in depth (a depth edge) are left out;
    # None keeps them (docs/decisions/0011-tuned-settings.md)
    edge_jump: float | None = Field(0.03, gt=0.0)
    # voxels observed this many times or fewer are not part of the surface (Open3D keeps the voxels whose summed
    # weight exceeds it): 1, the default, takes a surface seen by two frames or more
    min_weight: float = Field(1.0, ge=0.0)


class BatchConfig(_Model):
    """`leovr batch`: one Ray task per sequence, on a local Ray instance or an existing cluster."""

    # run on each sequence, with its own section's settings
    job: Literal["refine", "complete"] = "refine"
    address: str | None = None  # None: start a local Ray instance; "auto" or HOST:PORT: join a running cluster
    workers: int | None = Field(None, ge=1)  # tasks in flight; None = the cluster's CPUs / cpus_per_task
    cpus_per_task: int = Field(1, ge=1)  # Ray's num_cpus per task; also the task's torch / OpenCV threads
    max_retries: int = Field(3, ge=0)  # a task whose worker dies is re-run (resuming) up to this often
    dashboard: bool = False  # start Ray's dashboard with a local instance (needs `pip install "ray[default]"`)
    map: bool = False  # refine jobs: also fuse each sequence's run into OUT/NAME/map (`leovr map`, the `map` section)


class LeovrConfig(_Model):
    """Every command's settings, a section each, and the one seed they all draw with."""

    # seeds every random draw: the rendered world and its drive (simulate, demo), the cheap input's ratio:R draws
    # and the graph's samples of returns and pixels (complete, refine), training's sampling and initialisation
    # (train, selfsup)
    seed: int = Field(0, ge=0)
    complete: CompleteConfig = CompleteConfig()
    simulate: SimulateConfig = SimulateConfig()
    demo: DemoConfig = DemoConfig()
    train: TrainConfig = TrainConfig()
    refine: RefineConfig = RefineConfig()
    selfsup: SelfSupConfig = SelfSupConfig()
    map: MapConfig = MapConfig()
    batch: BatchConfig = BatchConfig()

    @model_validator(mode="before")
    @classmethod
    def _seed_once(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for key, section in data.items():
                if isinstance(section, dict) and "seed" in section:
                    raise ValueError(f"{key}.seed: the seed is set once, at the top level (`seed: N`)")
        return data

    @model_validator(mode="after")
    def _seed_sections(self) -> LeovrConfig:
        for key in SEEDED_SECTIONS:
            section = getattr(self, key)
            if section.seed != self.seed:
                object.__setattr__(self, key, section.model_copy(update={"seed": self.seed}))
        return self

    @model_serializer(mode="wrap")
    def _without_section_seeds(self, handler: Any) -> dict[str, Any]:
        # the sections' copies of the seed are the top level's: a dump holds it once, as a config file does
        data = handler(self)
        for key in SEEDED_SECTIONS:
            if isinstance(data.get(key), dict):  # a partial dump (include / exclude) may leave a section out
                data[key].pop("seed", None)
        return data


# the sections whose jobs draw at random (each carries the top level's seed)
SEEDED_SECTIONS = ("complete", "simulate", "demo", "train", "refine", "selfsup")


def _describe(exc: ValidationError) -> str:
    """One line per invalid field: 'section.key: what is wrong' (a check across fields: what is wrong)."""

    def one(e: dict) -> str:
        msg = e["msg"].removeprefix("Value error, ")
        return f"{'.'.join(map(str, e['loc']))}: {msg}" if e["loc"] else msg

    return "; ".join(one(e) for e in exc.errors())


def load_model(path: str | Path | None, model: type[M]) -> M:
    """`model`'s defaults, overlaid with a YAML file when given; unknown keys and bad values are errors."""
    if path is None:
        return model()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    from leovr.data.io import read_yaml

    data = read_yaml(path) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {_describe(exc)}") from exc


def load_config(path: str | Path | None = None) -> LeovrConfig:
    """The product's settings: defaults, overlaid with a YAML file when given."""
    return load_model(path, LeovrConfig)


def _given(options: dict[str, Any]) -> dict[str, Any]:
    """The options that were given: None left out, in nested mappings too (an emptied mapping with them)."""
    given = {}
    for key, value in options.items():
        if isinstance(value, dict):
            value = _given(value) or None
        if value is not None:
            given[key] = value
    return given


def _merged(base: dict[str, Any], given: dict[str, Any]) -> dict[str, Any]:
    """`base` with `given` on top; a nested mapping is merged key by key, not replaced."""
    out = dict(base)
    for key, value in given.items():
        nested = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merged(out[key], value) if nested else value
    return out


def override(model: _Model, **options: Any) -> Any:
    """A copy of `model` with the options that were given (not None) applied and validated. A nested
    model's options come as a mapping and change only the keys they name:
    `override(cfg, window=6, loop={"enabled": True})`."""
    try:
        return model.model_validate(_merged(model.model_dump(), _given(options)))
    except ValidationError as exc:
        raise ConfigError(f"invalid option: {_describe(exc)}") from exc
