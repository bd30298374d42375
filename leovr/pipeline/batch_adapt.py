"""`leovr batch --job adapt+refine`: the generator adapted once to every sequence of the batch (Ray Train,
data-parallel), resumed or reused by a re-run of the same batch and settings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from tqdm import tqdm

from leovr.config import LeovrConfig
from leovr.data.io import write_text
from leovr.data.run_info import folder_fingerprint
from leovr.errors import DataError, LeovrError
from leovr.pipeline.batch_manifest import BatchItem
from leovr.pipeline.batch_state import ERROR_FILE, STATE_FILE, read_state, set_threads, task_settings
from leovr.pipeline.batch_summary import read_json_or_empty

ADAPT_DIR = "_adapt"  # the adapted generator of an adapt+refine batch


def _adapt_settings(items: list[BatchItem], cfg: LeovrConfig) -> dict:
    return task_settings(
        "adapt",
        {"sequences": {str(it.path): folder_fingerprint(it.path) for it in items}, "adapt": cfg.adapt.model_dump()},
    )


def adapt_done(items: list[BatchItem], cfg: LeovrConfig, out: Path) -> str | None:
    """The adapted checkpoint of an earlier run of the same batch and settings, if it finished."""
    out = Path(out).resolve()
    st = read_state(out)
    if (
        (out / "generator.pt").is_file()
        and st.get("status") == "done"
        and st.get("settings") == _adapt_settings(items, cfg)
    ):
        return str(out / "generator.pt")
    return None


def _adapt_loop(config: dict) -> None:
    """One process of the adaptation under Ray Train (its process group is Ray's): resumes from the
    last epoch after a worker died. A data error is written to ERROR_FILE by process 0, not raised, so
    that Ray Train does not retry what cannot succeed (every process reads the same frames and meets it)."""
    from leovr.config import AdaptConfig
    from leovr.data import open_sequence
    from selfsup.adapt import adapt
    from selfsup.distributed import distributed

    set_threads(config["threads"])
    folder = Path(config["folder"])
    resume = (folder / "checkpoint_last.pt").is_file()
    try:
        adapt(
            [open_sequence(p) for p in config["paths"]],
            AdaptConfig.model_validate(config["adapt"]),
            folder,
            resume=resume,
            progress=False,
        )
    except LeovrError as exc:
        if distributed()[0] == 0:
            write_text(folder / ERROR_FILE, json.dumps({"error": str(exc)}) + "\n")


def _resolved(acfg: Any) -> dict:
    """The adapt section with its starting checkpoint as an absolute path."""
    d = acfg.model_dump()
    if d.get("init_checkpoint"):
        d["init_checkpoint"] = str(Path(d["init_checkpoint"]).resolve())
    return d


def adapt_batch(items: list[BatchItem], cfg: LeovrConfig, out: Path, progress: bool = True) -> str:
    """Adapt the generator on every sequence of the batch, data-parallel with Ray Train's TorchTrainer
    (DistributedDataParallel over gloo): by default one process per node, holding that node's CPUs
    (on one machine, two processes with a thread each were no faster than one with two threads, and
    each process holds all the frames); `batch.adapt_processes` processes of `cpus_per_task` CPUs
    instead. Restarted from the last epoch up to `max_retries` times when a worker dies. Returns the
    adapted checkpoint's path."""
    import ray
    from ray.train import FailureConfig, RunConfig, ScalingConfig
    from ray.train.torch import TorchTrainer

    bcfg = cfg.batch
    if bcfg.adapt_processes:
        n, per = bcfg.adapt_processes, bcfg.cpus_per_task
    else:  # one process per node with that node's CPUs: threads within a node, data-parallel across nodes
        cpus = [
            int(nd["Resources"]["CPU"]) for nd in ray.nodes() if nd.get("Alive") and nd["Resources"].get("CPU", 0) >= 1
        ]
        n, per = max(1, len(cpus)), max(1, min(cpus, default=1))
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    (out / ERROR_FILE).unlink(missing_ok=True)
    if progress:
        tqdm.write(
            f"adapting the generator on {len(items)} sequence(s): {n} data-parallel process(es) on Ray Train -> {out}"
        )
    trainer = TorchTrainer(
        _adapt_loop,
        # absolute paths: Ray Train runs each process in a folder of its own
        train_loop_config={
            "paths": [str(Path(it.path).resolve()) for it in items],
            "adapt": _resolved(cfg.adapt),
            "folder": str(out),
            "threads": per,
        },
        scaling_config=ScalingConfig(num_workers=n, use_gpu=False, resources_per_worker={"CPU": per}),
        run_config=RunConfig(
            name="ray_train", storage_path=str(out), failure_config=FailureConfig(max_failures=bcfg.max_retries)
        ),
    )
    try:
        trainer.fit()
    except Exception as exc:  # Ray Train's failure after its retries (a worker died too often)
        raise DataError(out, f"adaptation on the batch's sequences failed, nothing refined: {exc}") from exc
    err = read_json_or_empty(out / ERROR_FILE).get("error")
    if err:
        raise DataError(out, f"adaptation on the batch's sequences failed, nothing refined: {err}")
    path = str(out / "generator.pt")
    write_text(
        out / STATE_FILE,
        json.dumps({"status": "done", "settings": _adapt_settings(items, cfg), "checkpoint": path, "processes": n})
        + "\n",
    )
    return path
