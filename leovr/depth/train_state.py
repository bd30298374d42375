"""What a training run keeps on disk between epochs, the same for supervised and self-supervised training:
`checkpoint_last.pt` to resume from (network, optimisers, schedule, epoch, settings, and the recordings it learns
from where they are known), the generator as trained so far (a checkpoint `leovr refine --checkpoint` loads), the
log (`log.jsonl`, `log.csv`); and the checks that a resumed run goes on with the same settings and recordings."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import torch

from leovr.config import NetworkSettings
from leovr.data.io import atomic_write, write_text
from leovr.depth.network import DepthGenerator, GeneratorConfig
from leovr.errors import DataError

# What every resume checkpoint holds (`resume_from` also asks for each optimiser and schedule by its name): the weights,
# the last finished epoch, the settings and the network
RESUME_KEYS = ("model", "epoch", "config", "network")


def save_checkpoint(path: Path, state: dict) -> None:
    atomic_write(path, lambda tmp: torch.save(state, tmp))


def generator_config(cfg: NetworkSettings) -> GeneratorConfig:
    """The network a training config describes; its fields are the `network` entry of every checkpoint."""
    return GeneratorConfig(
        lidar_encoder=cfg.lidar_encoder,
        cross_attention=cfg.cross_attention,
        channels=tuple(cfg.channels),
        blocks=tuple(cfg.blocks),
        output=cfg.output,
    )


def save_generator(path: Path, model: DepthGenerator, cfg: NetworkSettings, **extra: Any) -> None:
    """The generator as trained so far: a checkpoint inference loads (weights, network, settings, and `extra`)."""
    network, config = generator_config(cfg).__dict__, cfg.model_dump()
    save_checkpoint(path, {"model": model.state_dict(), "network": network, "config": config, **extra})


def save_last(
    path: Path,
    model: DepthGenerator,
    optimisers: dict[str, Any],
    epoch: int,
    cfg: NetworkSettings,
    inputs: dict[str, str] | None = None,
    **extra: Any,
) -> None:
    """The state to resume from after `epoch` (0-based): weights, each optimiser or schedule's state under its name,
    settings, the recordings trained on (`inputs`: path -> content fingerprint) and `extra`."""
    state = {
        "model": model.state_dict(),
        **{name: o.state_dict() for name, o in optimisers.items()},
        "epoch": epoch,
        "config": cfg.model_dump(),
        "network": generator_config(cfg).__dict__,
        "sequences": inputs,
        **extra,
    }
    save_checkpoint(path, state)


def read_resume_state(path: Path, keys: tuple[str, ...]) -> dict:
    """A trainer's `checkpoint_last.pt` with the given entries; one clear error when it is missing, truncated
    (an interrupted copy) or not a leovr checkpoint."""
    if not path.is_file():
        raise DataError(path, "nothing to resume from")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for corrupt files
        raise DataError(
            path,
            f"unreadable checkpoint (truncated, or not written by leovr): "
            f"{(str(exc).strip().splitlines() or [type(exc).__name__])[0]}",
        ) from exc
    missing = [k for k in keys if not isinstance(state, dict) or k not in state]
    if missing:
        raise DataError(path, f"not a leovr resume checkpoint (no {', '.join(missing)})")
    return state


def config_changes(saved: dict, cfg: NetworkSettings) -> list[str]:
    """Settings in which a run's saved config differs from `cfg`; a setting the saved config lacks (added
    to leovr after the run began) counts as its default."""
    default = type(cfg)().model_dump()
    return sorted(k for k, v in cfg.model_dump().items() if saved.get(k, default[k]) != v)


def resume_from(
    path: Path,
    model: DepthGenerator,
    optimisers: dict[str, Any],
    cfg: NetworkSettings,
    inputs: dict[str, str] | None = None,
    may_change: tuple[str, ...] = ("epochs",),
) -> dict:
    """The state saved by `save_last` at `path`, with the model and each optimiser or schedule restored from it.
    A checkpoint trained with other settings (other than `may_change`: how long to train) or on other recordings
    (`inputs`, where both runs know them) is refused: the run would silently become another one."""
    state = read_resume_state(path, RESUME_KEYS + tuple(optimisers))
    changed = [k for k in config_changes(state["config"], cfg) if k not in may_change]
    if changed:
        raise DataError(
            path,
            f"was trained with other settings ({', '.join(changed)}); resume with the same config (only "
            f"{', '.join(may_change)} may change) or start a new --out folder",
        )
    before = state.get("sequences")
    if before is not None and inputs is not None and before != inputs:
        other = sorted(set(before.items()) ^ set(inputs.items()))
        raise DataError(
            path,
            f"was trained on other recordings or other contents ({', '.join(p for p, _ in other)}); "
            "resume with the same sequences or start a new --out folder",
        )
    try:
        model.load_state_dict(state["model"])
        for name, o in optimisers.items():
            o.load_state_dict(state[name])
    except (RuntimeError, ValueError, KeyError) as exc:
        raise DataError(path, f"does not fit this network or optimiser: {exc}") from exc
    return state


def append_logs(out: Path, record: dict) -> None:
    """The epoch's record appended to `log.jsonl`, and `log.csv` rewritten from all of its lines."""
    with open(out / "log.jsonl", "a") as fh:
        fh.write(json.dumps(record) + "\n")
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines() if line.strip()]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "log.csv", buf.getvalue())
