"""Data-parallel helpers shared by the trainers: the process group that torchrun or Ray Train set up.

With `torchrun --nproc-per-node N` (env WORLD_SIZE > 1) the group is joined here (gloo, CPU); under
Ray Train's `TorchTrainer` it already exists. A single process gets rank 0 of 1 and no collectives.
"""

from __future__ import annotations

import os

import torch
import torch.distributed as dist


def distributed() -> tuple[int, int]:
    """(rank, world size); joins torchrun's process group (gloo) when there is more than one process."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        dist.init_process_group("gloo")
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def barrier(world: int) -> None:
    if world > 1:
        dist.barrier()


def _all_reduce(values: list[float], world: int, op: str) -> list[float]:
    if world == 1:
        return [float(v) for v in values]
    t = torch.tensor(values, dtype=torch.float64)
    dist.all_reduce(t, op=getattr(dist.ReduceOp, op))
    return t.tolist()


def all_sum(values: list[float], world: int) -> list[float]:
    """Element-wise sum over the processes (float64), for example error sums and counts."""
    return _all_reduce(values, world, "SUM")


def all_max(value: float, world: int) -> float:
    """The largest value over the processes (for example elapsed minutes, so that all stop together)."""
    return _all_reduce([value], world, "MAX")[0]


def raise_shared(error: Exception | None, world: int) -> None:
    """Raise on every process the error that process 0 met (None: none), so that the others do not
    wait for it in the next collective; they raise a LeovrError with its message. Call it on every
    process at the same point."""
    if world > 1:
        box = [None if error is None else str(error)]
        dist.broadcast_object_list(box, 0)
        if box[0] is not None and error is None:
            from leovr.errors import LeovrError

            error = LeovrError(box[0])
    if error is not None:
        raise error
