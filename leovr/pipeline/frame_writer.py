"""A run's per-frame files written beside the run: PNG compression leaves the interpreter lock, so a
writer thread compresses frame k's depth maps while the main thread optimises frame k + 1.

Writes happen in the order they were handed over, one at a time: a frame's progress record, handed over
after its files, is on disk only once they are (a resumed run never finds a pose without its depth).
A writer's error is raised in the main thread at the next hand-over or at `drain`."""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future
from types import TracebackType
from typing import Any, Callable

from leovr.threads import Worker


class FrameWriter:
    """Runs write jobs in one background thread, in order (`threaded=False`: at once, in the caller's
    thread, as a batch task with one CPU runs). At most `max_pending` jobs wait: memory stays bounded when
    writing is slower than the run."""

    def __init__(self, threaded: bool, max_pending: int = 4) -> None:
        self._worker = Worker("writer", threaded)
        self._pending: deque[Future] = deque()
        self.max_pending = max_pending

    def submit(self, job: Callable[..., Any], *args: Any) -> None:
        while self._pending and (self._pending[0].done() or len(self._pending) >= self.max_pending):
            self._pending.popleft().result()  # a failed write raises here
        self._pending.append(self._worker.submit(job, *args))

    def drain(self) -> None:
        """Wait until everything handed over is written (raising the first failure)."""
        while self._pending:
            self._pending.popleft().result()

    def close(self) -> None:
        try:
            self.drain()
        finally:
            self._worker.close()

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:  # the run failed: what was handed over is still written, its errors aside
            self._worker.close()
