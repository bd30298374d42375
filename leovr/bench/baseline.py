"""`leovr bench baseline`: classical completion on the shared KITTI raw clip with both cheap inputs."""

from __future__ import annotations

import time
from pathlib import Path

from leovr.bench.common import depth_entry, write_bench
from leovr.bench.config import BenchBaselineConfig
from leovr.config import CompleteConfig
from leovr.data import open_sequence
from leovr.errors import DataError
from leovr.pipeline.completion import ground_truth_note, run_completion


def run_baseline_bench(
    data: Path, out: Path, cfg: BenchBaselineConfig, quick: bool = False, progress: bool = True
) -> dict:
    """Fill `results.kitti_<input>.<method>` for every configured input and method."""
    if not data.exists():
        raise DataError(data, "KITTI raw clip not found (set LEOVR_SHARED_DATA or pass --data)")
    started = time.time()
    seq = open_sequence(data)
    step = cfg.quick_step if quick else 1
    results: dict[str, dict] = {}
    note = ""
    for inp in cfg.inputs:
        for method in cfg.methods:
            ccfg = CompleteConfig(method=method, input=inp, seed=cfg.seed, step=step)
            m = run_completion(seq, ccfg, out=None, progress=progress)
            results.setdefault(f"kitti_{ccfg.input}", {})[method] = depth_entry(m)
            note = ground_truth_note("heldout", ccfg)
    body = {
        "quick": quick,
        "sequence": str(seq.path),
        "frames": len(range(len(seq))[::step]),
        "ground_truth": note,
        "results": results,
    }
    return write_bench(out, "baseline", body, started)
