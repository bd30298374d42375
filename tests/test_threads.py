"""BLAS thread limit around the per-frame loops (leovr.threads)."""

from __future__ import annotations

import numpy  # noqa: F401  (loads numpy's BLAS)
from threadpoolctl import threadpool_info

from leovr.threads import single_threaded_blas


def _blas_threads() -> set[int]:
    return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}


def test_blas_is_single_threaded_inside_and_restored_after():
    before = _blas_threads()
    seen = single_threaded_blas(_blas_threads)()
    assert seen == {1}
    assert _blas_threads() == before


def test_the_pipelines_run_single_threaded_blas():
    from leovr.depth.train import train_supervised
    from leovr.pipeline.completion import run_completion
    from leovr.pipeline.refine import run_refine
    from selfsup.trainer import train_selfsup

    for fn in (run_refine, run_completion, train_supervised, train_selfsup):
        assert getattr(fn, "__wrapped__", None) is not None, fn.__name__
