"""Threads on a small CPU machine: BLAS limited to one thread in the per-frame loops, and the one mechanism
that runs a loop's side work (reading ahead, the generator, writing) in a thread of its own (`Worker`).

numpy, scipy and OpenCV each ship their own OpenBLAS, whose worker threads keep spinning for a while
after a call. In the per-frame loop a BLAS call in the classical prior (then scipy's Delaunay) left them
spinning on both cores while torch ran the network, which then took 1.4x as long
(docs/decisions/0011-tuned-settings.md). The loops' own BLAS work is small matrices, so they run with
single-threaded BLAS; torch (its own OpenMP pool) keeps its threads.
"""

from __future__ import annotations

import functools
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, TypeVar

F = TypeVar("F", bound=Callable)
R = TypeVar("R")


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


class Worker:
    """One background thread for one kind of side work (`leovr-NAME`), or none: with `threaded=False` (a batch task
    with one CPU) `submit` runs the job at once in the caller's thread. Either way it returns a future that holds
    the job's result or exception, raised where the caller takes it: the callers have one path."""

    def __init__(self, name: str, threaded: bool) -> None:
        self.pool = ThreadPoolExecutor(1, thread_name_prefix=f"leovr-{name}") if threaded else None

    @property
    def threaded(self) -> bool:
        return self.pool is not None

    def submit(self, job: Callable[..., R], *args: Any) -> Future[R]:
        if self.pool is not None:
            return self.pool.submit(job, *args)
        fut: Future[R] = Future()
        try:
            fut.set_result(job(*args))
        except Exception as exc:  # raised where the result is taken, as from the thread
            fut.set_exception(exc)
        return fut

    def close(self, cancel: bool = False) -> None:
        """Wait for the running job (`cancel`: drop those not started)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=cancel)


def done_future(value: R) -> Future[R]:
    """A future that holds `value` already."""
    fut: Future[R] = Future()
    fut.set_result(value)
    return fut
