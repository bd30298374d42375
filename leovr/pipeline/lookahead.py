"""The next frame prepared in a second thread while the main thread finishes the current one.

A frame-by-frame run hands its next frame's preparation (reading, the generator) to a worker thread as soon
as that frame's inputs are known, and takes the result when it reaches the frame; the files of the frame
after are read in a reader thread meanwhile. ONNX Runtime, OpenCV and image decoding leave the interpreter
lock, so the threads overlap. With one core's worth of threads (a batch task with one CPU) the preparation
runs in line instead: the results are the same either way.
"""

from __future__ import annotations

from concurrent.futures import Future
from types import TracebackType
from typing import Any, Callable, Generic, TypeVar

from leovr.threads import Worker, done_future

R = TypeVar("R")  # what the preparation of a frame gives
F = TypeVar("F")  # what reading a frame gives


class Lookahead(Generic[R, F]):
    """One frame's preparation in flight at a time (`submit`, then `result`), and frames read once each
    (`read_ahead` in the reader thread, `peek` / `take` by the preparation). An exception in the worker is
    raised by `result`, where the frame is used; in line, the same. Close it (or use it as a context
    manager) to cancel what has not started and to wait for what has."""

    def __init__(self, read: Callable[[int], F], threaded: bool) -> None:
        self.read = read
        self.ahead = Worker("generator", threaded)
        self.reader = Worker("read", threaded)
        self.reads: dict[int, Future] = {}  # frame index -> its read, running or done
        self.next: Future | None = None  # the submitted preparation, until `result` takes it

    @property
    def threaded(self) -> bool:
        return self.ahead.threaded

    @property
    def pending(self) -> bool:
        """Whether a preparation was submitted and its result not taken yet."""
        return self.next is not None

    def submit(self, prepare: Callable[..., R], *args: Any) -> None:
        """Start `prepare(*args)`: in the worker thread, or in line (its exception kept for `result`)."""
        self.next = self.ahead.submit(prepare, *args)

    def result(self) -> R:
        """The submitted preparation's result (waiting for it); its exception is raised here."""
        value = self.next.result()
        self.next = None
        return value

    def read_ahead(self, i: int) -> None:
        """Frame i read in the reader thread, unless it is read already; in line it is read when first needed."""
        if self.reader.threaded and i not in self.reads:
            self.reads[i] = self.reader.submit(self.read, i)

    def future(self, i: int) -> Future:
        """Frame i's read: started (in the reader thread, or here) unless it is already."""
        if i not in self.reads:
            self.reads[i] = self.reader.submit(self.read, i)
        return self.reads[i]

    def peek(self, i: int) -> F:
        """Frame i, read once (here, unless read ahead already) and kept for `take`."""
        if i not in self.reads:
            self.reads[i] = done_future(self.read(i))
        return self.reads[i].result()

    def take(self, i: int) -> F:
        """Frame i as read ahead or peeked (forgotten then), else read now."""
        return self.reads.pop(i).result() if i in self.reads else self.read(i)

    def close(self) -> None:
        """Cancel the preparation if it has not started and wait for it if it has; cancel reads not started."""
        if self.next is not None:
            self.next.cancel()
        self.ahead.close()
        self.reader.close(cancel=True)

    def __enter__(self) -> "Lookahead[R, F]":
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()
