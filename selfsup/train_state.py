"""What a self-supervised run keeps on disk between epochs: each epoch's checkpoints (`checkpoint_last.pt`
to resume from, `generator.pt` to load) and log line, and the checks that a resumed run goes on with the
same settings and recordings."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import torch

from leovr.config import SelfSupConfig
from leovr.data.io import write_text
from leovr.depth.network import DepthGenerator
from leovr.depth.train import generator_config, load_resume, save_checkpoint
from leovr.errors import DataError


def config_changes(saved: dict, cfg: SelfSupConfig) -> list[str]:
    """Settings in which a run's saved config differs from `cfg`; a setting the saved config lacks (added
    to leovr after the run began) counts as its default."""
    default = SelfSupConfig().model_dump()
    return sorted(k for k, v in cfg.model_dump().items() if saved.get(k, default[k]) != v)


def append_logs(out: Path, record: dict) -> None:
    """The epoch's record appended to `log.jsonl`, and `log.csv` rewritten from all of its lines."""
    with open(out / "log.jsonl", "a") as fh:
        fh.write(json.dumps(record) + "\n")
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines() if line.strip()]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[-1]))
    writer.writeheader()
    writer.writerows(rows)
    write_text(out / "log.csv", buf.getvalue())


def resumed_epoch(
    last: Path,
    model: DepthGenerator,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    cfg: SelfSupConfig,
    inputs: dict[str, str],
) -> int:
    """The epoch to go on from, the model, optimiser and schedule restored from `last`; a checkpoint trained
    with other settings (other than the number of epochs) or on other recordings (`inputs`: path -> content
    fingerprint) is refused."""
    state = load_resume(last, model, opt, sched)
    changed = [k for k in config_changes(state.get("config", {}), cfg) if k != "epochs"]
    if changed:
        raise DataError(
            last,
            f"was trained with other settings ({', '.join(changed)}); resume with the same "
            "config (only epochs may change) or start a new --out folder",
        )
    before = state.get("sequences")
    if before is not None and before != inputs:
        other = sorted(set(before.items()) ^ set(inputs.items()))
        raise DataError(
            last,
            f"was trained on other recordings or other contents ({', '.join(p for p, _ in other)}); "
            "resume with the same sequences or start a new --out folder",
        )
    return state["epoch"] + 1


def save_epoch(
    out: Path,
    model: DepthGenerator,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    epoch: int,
    cfg: SelfSupConfig,
    inputs: dict[str, str],
) -> None:
    """The state to resume from (`checkpoint_last.pt`, with the recordings' fingerprints `inputs`) and the
    generator as trained so far (`generator.pt`)."""
    network, config = generator_config(cfg).__dict__, cfg.model_dump()
    save_checkpoint(
        out / "checkpoint_last.pt",
        {
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "epoch": epoch,
            "config": config,
            "network": network,
            "sequences": inputs,
        },
    )
    save_checkpoint(
        out / "generator.pt",
        {"model": model.state_dict(), "network": network, "config": config, "epoch": epoch + 1, "mode": "selfsup"},
    )
