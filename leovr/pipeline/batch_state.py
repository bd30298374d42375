"""What `leovr batch` records of each sequence (DIR/<name>/batch.json): the settings a result depends on, whether
it is done, and the refusal to mix two runs' results in one folder."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from leovr.data.run_info import differences, folder_fingerprint
from leovr.errors import DataError, brief
from leovr.pipeline.batch_manifest import BatchItem
from leovr.pipeline.batch_summary import read_json_or_empty

STATE_FILE = "batch.json"


def task_settings(
    job: str, section: dict[str, Any], path: Path | None = None, map_section: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What a sequence's result depends on (the job, its settings, the map's when one is fused, the sequence's
    files): a re-run with other settings or changed data is refused before any work."""
    files = folder_fingerprint(path) if path is not None and Path(path).exists() else None
    record = {"job": job, "config": section, "files_sha1": files} | ({"map": map_section} if map_section else {})
    return json.loads(json.dumps(record, default=str))


def read_state(folder: Path) -> dict:
    return read_json_or_empty(folder / STATE_FILE)


def is_done(folder: Path, settings: dict) -> bool:
    st = read_state(folder)
    return st.get("status") == "done" and st.get("settings") == settings and (folder / "metrics.json").is_file()


def check_no_other_results(out: Path, items: list[BatchItem], settings: dict[str, dict]) -> None:
    """Refuse, before any work, a batch whose output folders hold results of other settings or other input
    files: resuming into them would mix two runs, and replacing them would lose results already written."""
    stale = []
    for it in items:
        folder = out / it.name
        if not (folder / "run.json").is_file():
            continue
        prev = read_state(folder).get("settings")
        if prev != settings[it.name]:
            diff = differences(prev, settings[it.name]) if isinstance(prev, dict) else ["no batch.json"]
            stale.append(f"{it.name}: {brief(diff, 2, '; ')}")
    if stale:
        raise DataError(
            out,
            f"holds results of other settings or input files for {brief(stale, 3, ', ')}; "
            "use a new --out, or delete those sequences' folders to do them again",
        )


def set_threads(n: int) -> None:
    import cv2
    import torch

    torch.set_num_threads(n)
    cv2.setNumThreads(n)
