"""The epoch loop every trainer runs (supervised, self-supervised from a cold start or fine-tuning): each epoch what the
trainer sets up (`begin`: the model's mode, the batches, the optimiser that steps, the loss of a batch), a step per
batch, then what it does between epochs (`end`: the schedule, evaluation, logs and checkpoints, the files of
`leovr.depth.train_state`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import torch
from tqdm import tqdm

BatchLoss = Callable[[dict], tuple[torch.Tensor, dict[str, float]]]  # batch -> (loss, named terms, detached)


@dataclass
class Epoch:
    """What one epoch trains: its batches, the optimiser that steps, the loss of a batch and the progress bar's
    label."""

    batches: Iterable[dict]
    optimizer: torch.optim.Optimizer
    loss: BatchLoss
    label: str


def train_epochs(
    epochs: Iterable[int],
    begin: Callable[[int], Epoch],
    end: Callable[[int, dict[str, float], float], dict],
    show: bool = True,
) -> dict:
    """Every epoch: `begin(epoch)`, a step of its optimiser per batch, then `end(epoch, means of the terms over
    the batches, seconds)`, which returns the epoch's log record; returns the last epoch's record."""
    record: dict = {}
    for epoch in epochs:
        work = begin(epoch)
        t0 = time.time()
        means = run_epoch(work, show)
        record = end(epoch, means, time.time() - t0)
    return record


def run_epoch(work: Epoch, show: bool) -> dict[str, float]:
    """One pass over the epoch's batches, a step per batch; the mean of each term."""
    sums: dict[str, float] = {}
    count = 0
    bar = tqdm(work.batches, desc=work.label, unit="batch", disable=not show)
    for batch in bar:
        loss, terms = work.loss(batch)
        work.optimizer.zero_grad()
        loss.backward()
        work.optimizer.step()
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + v
        count += 1
        bar.set_postfix(loss=f"{loss.item():.3f}")
    return {k: v / count for k, v in sums.items()}
