"""The data-parallel process group of the self-supervised trainer under `torchrun --nproc-per-node N` (env
WORLD_SIZE > 1; gloo, CPU), joined here, or one set up before (the caller's). A single process gets rank 0 of 1
and no collectives.
"""

from __future__ import annotations

import os

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
