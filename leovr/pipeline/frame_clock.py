"""A frame's turn in a frame-by-frame run on two clocks: the run's wall clock (from the end of the previous frame's
turn, so work that overlaps in other threads is counted once) and the process's CPU clock (every thread, user +
system)."""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator


class FrameClock:
    """`stage` times one stage of the frame (wall, ms); `turn` closes the frame's turn: its wall and CPU
    milliseconds, and the next turn starts."""

    def __init__(self) -> None:
        self.restart()

    def restart(self) -> None:
        """The next turn starts now."""
        self.wall0, self.cpu0 = time.perf_counter(), time.process_time()

    @contextmanager
    def stage(self, times: list[float]) -> Iterator[None]:
        """The span's wall time (ms) appended to `times`."""
        t = time.perf_counter()
        yield
        times.append(1000.0 * (time.perf_counter() - t))

    def turn(self) -> tuple[float, float]:
        """The frame's wall and CPU milliseconds since the turn started; restarts."""
        wall = 1000.0 * (time.perf_counter() - self.wall0)
        cpu = 1000.0 * (time.process_time() - self.cpu0)
        self.restart()
        return wall, cpu
