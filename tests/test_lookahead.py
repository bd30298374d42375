"""The next frame prepared ahead in a worker thread (leovr.pipeline.lookahead)."""

from __future__ import annotations

import threading

import pytest

from leovr.pipeline.lookahead import Lookahead


def _prepared(threaded: bool, frames: int = 5) -> list[tuple[int, str]]:
    """Each frame prepared one ahead, as refine hands them over: frame n + 1 submitted while n is used."""
    with Lookahead(lambda i: f"frame {i}", threaded) as ahead:
        got = []
        for n in range(frames):
            if not ahead.pending:
                ahead.submit(lambda i: (i, ahead.take(i)), n)
            got.append(ahead.result())
            if n + 1 < frames:
                ahead.read_ahead(n + 1)
                ahead.submit(lambda i: (i, ahead.take(i)), n + 1)
    return got


@pytest.mark.parametrize("threaded", [True, False])
def test_results_come_in_order(threaded):
    assert _prepared(threaded) == [(n, f"frame {n}") for n in range(5)]


def test_sequential_mode_gives_the_threaded_results():
    assert _prepared(threaded=False) == _prepared(threaded=True)


@pytest.mark.parametrize("threaded", [True, False])
def test_an_exception_in_the_worker_is_raised_at_that_frames_result(threaded):
    def prepare(i: int) -> int:
        if i == 2:
            raise ValueError(f"bad frame {i}")
        return i

    with Lookahead(lambda i: i, threaded) as ahead:
        for n in range(2):
            ahead.submit(prepare, n)
            assert ahead.result() == n
        ahead.submit(prepare, 2)  # no exception here: the frame is not used yet
        with pytest.raises(ValueError, match="bad frame 2"):
            ahead.result()


@pytest.mark.parametrize("threaded", [True, False])
def test_a_frame_is_read_once_and_taken_once(threaded):
    reads = []

    def read(i: int) -> str:
        reads.append(i)
        return f"frame {i}"

    with Lookahead(read, threaded) as ahead:
        ahead.read_ahead(1)
        ahead.read_ahead(1)  # already being read
        assert ahead.peek(1) == "frame 1"  # waits for the read ahead
        assert ahead.peek(2) == "frame 2"  # read here, kept
        assert ahead.take(1) == "frame 1" and ahead.take(2) == "frame 2"
        assert reads == [1, 2]
        assert ahead.take(1) == "frame 1"  # forgotten once taken: read again
        assert reads == [1, 2, 1]


def test_the_sequential_mode_reads_in_line():
    with Lookahead(lambda i: i, threaded=False) as ahead:
        assert not ahead.threaded
        ahead.read_ahead(3)  # no reader thread: nothing read ahead
        assert ahead.reads == {}


def test_shutdown_cancels_a_pending_read():
    started, release, reads = threading.Event(), threading.Event(), []

    def read(i: int) -> int:
        reads.append(i)
        started.set()
        release.wait(5)
        return i

    ahead = Lookahead(read, threaded=True)
    ahead.read_ahead(0)
    assert started.wait(5)  # the reader thread is busy with frame 0
    ahead.read_ahead(1)  # queued behind it
    threading.Timer(0.2, release.set).start()
    ahead.close()  # cancels frame 1's read, waits for frame 0's
    assert ahead.reads[1].cancelled()
    assert ahead.reads[0].result() == 0
    assert reads == [0]


def test_closing_waits_for_the_preparation_in_flight():
    release, done = threading.Event(), []

    def prepare(i: int) -> None:
        release.wait(5)
        done.append(i)

    ahead = Lookahead(lambda i: i, threaded=True)
    ahead.submit(prepare, 7)
    threading.Timer(0.2, release.set).start()
    ahead.close()
    assert done == [7]
