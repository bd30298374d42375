"""Thread pools on a small CPU machine.

numpy, scipy and OpenCV each ship their own OpenBLAS, whose worker threads keep spinning for a while
after a call. In the per-frame loop a BLAS call in the classical prior (then scipy's Delaunay) left them
spinning on both cores while torch ran the network, which then took 1.4x as long
(docs/decisions/0011-tuned-settings.md). The loops' own BLAS work is small matrices, so they run with
single-threaded BLAS; torch (its own OpenMP pool) keeps its threads.
"""

from __future__ import annotations

import functools
from typing import Callable, TypeVar

F = TypeVar("F", bound=Callable)


def single_threaded_blas(fn: F) -> F:
    """Run `fn` with every loaded BLAS library limited to one thread, restored afterwards."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        import cv2  # noqa: F401  (load each BLAS copy so that the limit reaches it)
        import scipy.linalg  # noqa: F401
        import scipy.spatial  # noqa: F401
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def torch_threads() -> int:
    """torch's intra-op thread count: above one, the refine run reads and writes in worker threads."""
    import torch

    return torch.get_num_threads()
