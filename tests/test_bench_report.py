"""docs/benchmarks.md is generated from docs/results/*.json (`tools/gen_docs.py`): the committed file
matches the JSON, and the renderer shows what a depth result holds and says which results are missing."""

from __future__ import annotations

import json
import time
from pathlib import Path

from leovr.bench.common import write_bench
from leovr.bench.report import BENCHES, render

ROOT = Path(__file__).resolve().parents[1]


def _method(mae: float, rmse: float, absrel: float, delta1: float) -> dict:
    bins = {"0-20": {"mae_m": mae / 2, "n": 10}, "20-40": {"mae_m": mae * 2, "n": 5}}
    return {
        "mae_m": mae,
        "rmse_m": rmse,
        "absrel": absrel,
        "delta1": delta1,
        "n": 15,
        "ms_per_frame": 12.5,
        "bins": bins,
    }


def _depth_doc() -> dict:
    return {
        "benchmark": "depth",
        "leovr_version": "0.1.0",
        "command": ".venv/bin/leovr bench depth --out runs/bench_depth_old.json",
        "machine": {"platform": "TestOS-1", "python": "3.11.7", "processor": ""},
        "date_utc": "2030-01-02T03:04:05Z",
        "duration_s": 12.34,
        "commit": "abc1234-dirty",
        "results": {
            "kitti_mid40": {
                "nearest": _method(2.0, 4.0, 0.25, 0.5),
                "ipbasic": _method(2.5, 4.5, 0.3, 0.45),
                "generator": _method(1.23456, 3.0, 0.125, 0.875),
                "brand_new_method": _method(0.5, 1.0, 0.05, 0.99),
                "not_a_method": {"note": "ignored"},
            }
        },
        "summary": {"kitti_mid40": {"generator_mae_vs_ipbasic": 0.49}},
    }


def test_committed_benchmarks_md_is_generated_from_results():
    doc = ROOT / "docs" / "benchmarks.md"
    expected = render(ROOT / "docs" / "results")
    assert doc.read_text() == expected, "docs/benchmarks.md is stale: run `python tools/gen_docs.py`"


def test_render_depth_result_and_missing_benches(tmp_path: Path):
    (tmp_path / "depth.json").write_text(json.dumps(_depth_doc()))
    text = render(tmp_path)
    assert text.startswith("# Benchmarks\n") and "do not edit by hand" in text
    section = text[text.index("## depth") : text.index("## refine")]
    assert "`leovr bench depth --out docs/results/depth.json`" in section and "runs/" not in section
    assert "2030-01-02T03:04:05Z" in section and "12.3 s" in section and "abc1234-dirty" in section
    assert "TestOS-1" in section
    main, bins = section.split("per ground-truth distance bin")
    rows = {line.split(" | ")[1]: line for line in main.splitlines() if line.startswith("| ") and " | " in line}
    assert set(rows) >= {"nearest", "ipbasic", "generator", "brand_new_method"} and "not_a_method" not in rows
    gen = rows["generator"]
    assert "| 1.235 | 3.000 | 0.125 | 0.875 | 12.5 |" in gen
    assert gen.rstrip(" |").endswith("0.49x")  # MAE against the baseline the summary names (ipbasic)
    assert "| generator | 0.617 | 2.469 |" in bins  # the generator's MAE per distance bin
    for name in BENCHES:
        if name != "depth":
            assert f"`docs/results/{name}.json` is missing" in text
    assert "`docs/results/depth.json` is missing" not in text


def test_render_empty_folder_names_every_missing_bench(tmp_path: Path):
    text = render(tmp_path)
    for name in BENCHES:
        assert f"## {name}" in text and f"`docs/results/{name}.json` is missing" in text


def test_missing_keys_render_as_dash(tmp_path: Path):
    doc = _depth_doc()
    del doc["results"]["kitti_mid40"]["generator"]["rmse_m"], doc["date_utc"], doc["machine"]
    (tmp_path / "depth.json").write_text(json.dumps(doc))
    gen = next(line for line in render(tmp_path).splitlines() if line.startswith("|  | generator |"))
    assert "| 1.235 | - | 0.125 |" in gen


def test_bench_json_records_the_commit(tmp_path: Path):
    doc = write_bench(tmp_path / "b.json", "demo", {}, time.time(), argv=["leovr", "bench", "demo"])
    assert "commit" in doc and (doc["commit"] is None or isinstance(doc["commit"], str) and doc["commit"])
    assert json.loads((tmp_path / "b.json").read_text())["commit"] == doc["commit"]


def test_a_selfsup_run_of_the_kitti_part_alone_names_no_synthetic_or_traffic_data():
    """`leovr bench selfsup --parts kitti`: the section lists only what ran."""
    from leovr.bench.report_selfsup import render_selfsup

    entry = {
        "test_frames": [64, 96],
        "train_minutes": {"cold_start": 4.5, "fine_tuned": 9.0},
        **{m: {"mae_m": v} for m, v in {"prior": 1.072, "untrained": 1.072, "shipped": 1.108}.items()},
        "cold_start": {"mae_m": 0.97},
        "fine_tuned": {"mae_m": 1.2},
        "other_clips": {"kitti_raw": {"shipped": 0.6, "cold_start": 0.7, "fine_tuned": 0.66}},
    }
    doc = {"parts": ["kitti"], "train_sequences": [], "results": {"kitti": {"kitti_raw_0013": {"vlp16": entry}}}}
    data, body = render_selfsup(doc)
    assert data == [] and not any("traffic" in line for line in body)
    row = next(line for line in body if line.startswith("| kitti_raw_0013 | vlp16 | 64-95 |"))
    assert "| 1.072 | 1.072 | 1.108 | 0.970 | 1.200 | 0.88x | 1.08x | 1.10x | 4.5 | 9.0 |" in row


def test_a_bench_records_its_command_as_a_user_types_it():
    from leovr.bench.common import command_line

    for prog in ("/x/.venv/bin/leovr", "/tmp/clone/leovr/cli.py", "-c"):  # -c: python -c "...main()"
        assert command_line([prog, "bench", "speed", "--out", "s.json"]) == "leovr bench speed --out s.json"
    assert command_line(["tools/other.py", "--x"]) == "tools/other.py --x"
