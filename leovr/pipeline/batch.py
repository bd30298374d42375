"""`leovr batch`: refine (or complete) many sequences, one Ray task per sequence.

Ray schedules the tasks (local instance by default, an existing cluster with `address`), re-runs a task
whose worker died (`max_retries`), and each task resumes its sequence from what was already written:
`leovr refine` writes every finished frame atomically, so a killed worker or driver loses at most the
frames in flight. A sequence that fails on its data fails alone: its error goes to the summary and the
others finish. `DIR/<name>/batch.json` records each sequence's state; a re-run skips those done with
the same settings, and refuses an output folder holding another run's results of a sequence.
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tqdm import tqdm

from leovr.config import BatchConfig, LeovrConfig, override
from leovr.data.io import check_output_dir, write_text
from leovr.errors import ConfigError, LeovrError, brief
from leovr.pipeline.batch_manifest import BatchItem
from leovr.pipeline.batch_state import (
    STATE_FILE,
    check_no_other_results,
    is_done,
    read_state,
    set_threads,
    task_settings,
)
from leovr.pipeline.batch_summary import write_summary

# a local instance without the dashboard: nothing reads Ray's own metrics, and not collecting them spares the
# raylet's wait for the metrics agent at start (docs/benchmarks.md)
LOCAL_SYSTEM_CONFIG = {"enable_metrics_collection": False}


def run_sequence(
    item: BatchItem,
    job: str,
    section: dict[str, Any],
    out: Path,
    threads: int = 1,
    settings: dict | None = None,
    topics: Any = None,
    map_section: dict[str, Any] | None = None,
) -> dict:
    """One sequence, in a Ray worker (or in-process): run the job into `out`, resuming what is there.
    `settings`: its `task_settings` when the caller has them; `topics`: the ROS bag topics the command line
    named (a worker process does not share the driver's). Returns the state record; data and config errors
    are recorded as a failure, not raised."""
    from leovr.data import open_sequence, rosbag

    if topics is not None:
        rosbag.CHOICE = topics
    set_threads(threads)
    settings = settings if settings is not None else task_settings(job, section, item.path, map_section)
    if is_done(out, settings):
        return {**read_state(out), "status": "skipped"}
    out.mkdir(parents=True, exist_ok=True)
    prev = read_state(out)
    attempts = int(prev.get("attempts", 0)) + 1 if prev.get("settings") == settings else 1
    state = {
        "name": item.name,
        "path": str(item.path),
        "job": job,
        "settings": settings,
        "attempts": attempts,
        "pid": os.getpid(),
        "host": os.uname().nodename,
    }
    write_text(out / STATE_FILE, json.dumps({**state, "status": "running"}, indent=1) + "\n")
    t0 = time.perf_counter()
    resume = (out / "run.json").is_file()
    try:
        seq = open_sequence(item.path)
        if job == "complete":
            from leovr.config import CompleteConfig
            from leovr.pipeline.completion import run_completion

            run_completion(seq, CompleteConfig.model_validate(section), out, resume=resume, progress=False)
        else:
            from leovr.config import RefineConfig
            from leovr.pipeline.refine import run_refine

            run_refine(seq, RefineConfig.model_validate(section), out, resume=resume, progress=False)
            if map_section is not None:
                from leovr.config import MapConfig
                from leovr.pipeline.tsdf_map import map_run

                map_run(out, out / "map", MapConfig.model_validate(map_section), progress=False)
        status, error = "done", ""
    except (LeovrError, ValueError) as exc:  # pydantic's ValidationError is a ValueError
        status, error = "failed", str(exc).replace("\n", " ")
    except Exception as exc:  # anything else on this sequence's data: recorded, the batch goes on
        status, error = "failed", f"{type(exc).__name__}: {exc}".replace("\n", " ")
    state |= {"status": status, "error": error, "wall_s": round(time.perf_counter() - t0, 2)}
    write_text(out / STATE_FILE, json.dumps(state, indent=1) + "\n")
    return state


def job_section(cfg: LeovrConfig, job: str, item: BatchItem) -> dict[str, Any]:
    """The job's config section with the sequence's own options applied."""
    base = cfg.complete if job == "complete" else cfg.refine
    opts = dict(item.options)
    unknown = sorted(set(opts) - set(type(base).model_fields))
    if unknown:
        raise ConfigError(
            f"{item.path}: unknown option(s) {', '.join(unknown)} for `{job}` "
            f"(known: {', '.join(type(base).model_fields)})"
        )
    return override(base, **opts).model_dump()


def _init_ray(bcfg: BatchConfig) -> bool:
    """Start or join Ray; True when this call started it (and so shuts it down)."""
    import ray

    if ray.is_initialized():
        return False
    if bcfg.address:
        ray.init(address=bcfg.address, log_to_driver=False)
    else:
        os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a private local instance needs no token
        cpus = (bcfg.workers or os.cpu_count() or 1) * bcfg.cpus_per_task
        system = {} if bcfg.dashboard else LOCAL_SYSTEM_CONFIG
        ray.init(
            num_cpus=cpus,
            include_dashboard=bcfg.dashboard,
            log_to_driver=False,
            configure_logging=False,
            _system_config=system,
        )
    return True


def run_batch(items: list[BatchItem], cfg: LeovrConfig, out: Path, progress: bool = True) -> list[dict]:
    """Run `cfg.batch.job` over `items` into `out/<name>/`; writes out/summary.csv, summary.md and
    mae_per_sequence.png after every finished sequence. Returns one state record per sequence. Ray is
    started (or joined) only when there is work left."""
    bcfg = cfg.batch
    out = check_output_dir(Path(out))
    job = bcfg.job
    rows: dict[str, dict] = {}
    sections: dict[str, dict] = {}
    bad = []
    for it in items:  # a bad option (a typo, a value out of range) refuses the batch before any work
        try:
            sections[it.name] = job_section(cfg, job, it)
        except LeovrError as exc:
            bad.append(f"{it.name}: {exc}")
    if bad:
        raise ConfigError(f"bad per-sequence option(s), nothing run: {brief(bad, 3, '; ')}")
    live = list(items)
    started = finished = False
    try:
        map_section = cfg.map.model_dump() if bcfg.map and job == "refine" else None
        settings = {it.name: task_settings(job, sections[it.name], it.path, map_section) for it in live}
        check_no_other_results(out, live, settings)
        todo = []
        for it in live:
            if is_done(out / it.name, settings[it.name]):
                rows[it.name] = {**read_state(out / it.name), "status": "skipped"}
            else:
                todo.append(it)
        if todo:
            started = _init_ray(bcfg)
            _run_tasks(todo, job, sections, settings, bcfg, out, rows, items, progress, map_section)
        finished = True
    finally:  # an interrupted batch keeps the summary written after its last finished sequence
        ordered = [rows[it.name] for it in items] if finished else None
        _finish(out, ordered, started)
    return ordered


def _finish(out: Path, rows: list[dict] | None, stop_ray: bool) -> None:
    """Write the final summary with its plot (when `rows`) while Ray shuts down (about 1.4 s spent
    waiting on its processes here), so that the two overlap instead of adding up; an error writing it
    is raised here."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="batch-summary") as pool:
        summary = pool.submit(write_summary, out, rows, plot=True) if rows is not None else None
        if stop_ray:
            import ray

            ray.shutdown()
    if summary is not None:
        summary.result()


def _run_tasks(
    todo: list[BatchItem],
    job: str,
    sections: dict[str, dict],
    settings: dict[str, dict],
    bcfg: BatchConfig,
    out: Path,
    rows: dict[str, dict],
    items: list[BatchItem],
    progress: bool,
    map_section: dict | None = None,
) -> None:
    """One Ray task per sequence of `todo`, at most `workers` in flight; the summary after each one."""
    import ray

    from leovr.data import rosbag

    task = ray.remote(run_sequence).options(
        num_cpus=bcfg.cpus_per_task, max_retries=bcfg.max_retries, retry_exceptions=False
    )
    limit = bcfg.workers or max(1, int(ray.cluster_resources().get("CPU", 1)) // bcfg.cpus_per_task)
    todo = list(todo)
    inflight: dict[Any, BatchItem] = {}
    bar = tqdm(
        total=len(items), initial=len(items) - len(todo), desc=f"batch {bcfg.job}", unit="seq", disable=not progress
    )
    while todo or inflight:
        while todo and len(inflight) < limit:
            it = todo.pop(0)
            inflight[
                task.remote(
                    it,
                    job,
                    sections[it.name],
                    out / it.name,
                    bcfg.cpus_per_task,
                    settings[it.name],
                    rosbag.CHOICE,
                    map_section,
                )
            ] = it
        ready, _ = ray.wait(list(inflight), num_returns=1)
        it = inflight.pop(ready[0])
        try:
            rows[it.name] = ray.get(ready[0])
        except ray.exceptions.RayError as exc:  # the worker died more often than max_retries allows
            rows[it.name] = {
                "name": it.name,
                "path": str(it.path),
                "status": "failed",
                "error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}",
            }
        bar.update(1)
        bar.set_postfix_str(f"{it.name}: {rows[it.name]['status']}")
        write_summary(
            out,
            [rows.get(i.name) or {"name": i.name, "path": str(i.path), "status": "pending"} for i in items],
            plot=False,
        )
    bar.close()
