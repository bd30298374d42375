"""`leovr bench selfsup --quick` on an empty cache (as on a fresh clone): it renders its own small dataset
and writes the contract's keys, including the traffic runs and the mask scores."""

from __future__ import annotations

import pytest
import json

import torch

from leovr.bench.selfsup import run_selfsup_bench
from leovr.bench.selfsup_models import untrained_generator
from leovr.bench.config import BenchSelfSupConfig
from leovr.config import SelfSupConfig


@pytest.mark.slow
def test_bench_selfsup_quick_contract(tmp_path, monkeypatch):
    monkeypatch.setenv("LEOVR_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "selfsup.json"
    run_selfsup_bench(
        out,
        BenchSelfSupConfig(parts=["synthetic", "traffic"], quick_frames=6, quick_epochs=1),
        quick=True,
        progress=False,
    )
    doc = json.loads(out.read_text())
    r = doc["results"]
    assert doc["quick"] and doc["parts"] == ["synthetic", "traffic"] and "kitti" not in r
    assert all(r[f"{k}_mae_m"] > 0 for k in ("untrained", "selfsup", "selfsup_nomask", "supervised"))
    assert {
        "selfsup",
        "selfsup_nomask",
        "selfsup_eq19_only",
        "selfsup_oracle_mask",
        "mask_gain",
        "oracle_mask_gain",
    } <= set(r["traffic_only"])
    assert doc["traffic_test_sequences"] and all("traffic" in p for p in doc["traffic_test_sequences"])
    for stage in ("mask_quality", "mask_quality_refine"):
        q = r[stage]
        for v in ("eq19", "rigid", "depth", "movers", "auto", "eq19_rigid", "eq19_movers", "full"):
            assert 0.0 <= q[v]["precision"] <= 1.0 and 0.0 <= q[v]["recall"] <= 1.0
        assert 0.0 < q["moving_share"] < 1.0 and 0.0 <= q["moving_with_depth"] <= 1.0
    assert "revisit" in doc["loop_closure_note"]


def test_untrained_reference_does_not_depend_on_what_ran_before():
    cfg = SelfSupConfig(channels=[8, 8, 16, 16, 16], blocks=[1, 1, 1, 1])
    a = untrained_generator(cfg).state_dict()
    torch.rand(1000)  # what a training run before it would consume
    b = untrained_generator(cfg).state_dict()
    c = untrained_generator(cfg.model_copy(update={"seed": 1})).state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)
