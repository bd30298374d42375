"""The refine run's background writer: jobs in the order handed over, a bounded queue, and a failed
write raised in the caller's thread."""

from __future__ import annotations

import threading
import time

import pytest

from leovr.pipeline.frame_writer import FrameWriter


@pytest.mark.parametrize("threaded", [True, False])
def test_jobs_run_in_order_and_the_queue_is_bounded(threaded):
    done: list[int] = []
    threads: set[str] = set()
    waiting: list[int] = []

    def job(k: int) -> None:
        time.sleep(0.01)
        threads.add(threading.current_thread().name)
        done.append(k)

    with FrameWriter(threaded, max_pending=2) as w:
        for k in range(8):
            w.submit(job, k)
            waiting.append(len(w._pending))
        assert max(waiting) <= 2
    assert done == list(range(8))
    assert (threading.main_thread().name in threads) != threaded


def test_a_failed_write_is_raised_in_the_callers_thread():
    def fail() -> None:
        raise OSError("disk full")

    w = FrameWriter(True)
    w.submit(fail)
    with pytest.raises(OSError, match="disk full"):
        w.drain()
    w.close()
