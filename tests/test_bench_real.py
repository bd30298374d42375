"""`leovr bench real` contract on a small configuration of the shared KITTI raw drives."""

from __future__ import annotations

import pytest
import json

from leovr.bench.real import METHODS, run_real_bench
from leovr.bench.config import BenchRealConfig
from tests.conftest import KITTI_RAW, KITTI_RAW_POSES, needs_posed_drive, needs_shared


@pytest.mark.slow
@needs_shared
def test_bench_real_contract(tmp_path):
    cfg = BenchRealConfig(clips=[str(KITTI_RAW)], inputs=["vlp16"], quick_frames=5, causal=False)
    doc = run_real_bench(tmp_path / "real.json", cfg, quick=True, progress=False)
    assert json.loads((tmp_path / "real.json").read_text())["benchmark"] == "real"
    clip = doc["clips"]["kitti_raw"]
    assert clip["development"] and not clip["has_poses"] and clip["trajectory"] == {}
    assert set(clip["results"]) == {"shipped_vlp16"}
    r = clip["results"]["shipped_vlp16"]
    # VLP-16-like input spins: no earlier scans join the generator's, so no single-frame or accumulated rows
    assert (
        set(r)
        == set(METHODS) - {"generator_frame", "nearest_accumulated", "ipbasic_accumulated"}
        == {"nearest", "ipbasic", "interp", "generator", "refined"}
    )
    ns = {m: v["n"] for m, v in r.items()}
    assert len(set(ns.values())) == 1 and min(ns.values()) > 1000  # every method on the same pixels
    for v in r.values():
        assert {"mae_m", "rmse_m", "absrel", "delta1", "n", "bins"} <= set(v) and v["mae_m"] > 0
    # the shipped generator and the graph over it beat the nearest fill on the same pixels
    assert max(r["generator"]["mae_m"], r["refined"]["mae_m"]) < 0.85 * r["nearest"]["mae_m"], r
    assert doc["pooled"]["results"]["shipped_vlp16"]["nearest"]["n"] == r["nearest"]["n"]  # one clip: pooled = it
    assert "held-out LiDAR points" in doc["ground_truth"]


@pytest.mark.slow
@needs_shared
@needs_posed_drive
def test_bench_real_pools_clips_and_scores_trajectories_where_poses_exist(tmp_path):
    cfg = BenchRealConfig(clips=[str(KITTI_RAW), str(KITTI_RAW_POSES)], inputs=["vlp16"], quick_frames=5)
    doc = run_real_bench(tmp_path / "real.json", cfg, quick=True, progress=False)
    one, two = doc["clips"]["kitti_raw"], doc["clips"]["kitti_raw_0013"]
    # every input also runs causal (live use), scored on its own held-out pixels
    assert set(one["results"]) == set(two["results"]) == {"shipped_vlp16", "causal_vlp16"}
    for clip in (one, two):
        for r in clip["results"].values():
            assert r["refined"]["mae_m"] < 0.85 * r["nearest"]["mae_m"], r
    n = [c["results"]["shipped_vlp16"]["nearest"]["n"] for c in (one, two)]
    assert doc["pooled"]["results"]["shipped_vlp16"]["nearest"]["n"] == sum(n)  # every scored pixel of both clips
    t = two["trajectory"]["vlp16"]
    assert {"leovr", "kiss_icp", "kiss_icp_no_deskew"} <= set(t) and t["leovr"]["ate_m"] > 0
    best = min(t["kiss_icp"]["ate_m"], t["kiss_icp_no_deskew"]["ate_m"])
    assert abs(t["leovr_vs_kiss_icp"] - t["leovr"]["ate_m"] / best) < 1e-9
    assert doc["pooled"]["trajectory_vs_kiss_icp"]["vlp16"] == t["leovr_vs_kiss_icp"]  # the one clip with poses
    assert (
        set(two["trajectory"]) == {"vlp16", "causal_vlp16"} and two["trajectory"]["causal_vlp16"]["leovr"]["ate_m"] > 0
    )


def test_a_bench_work_folder_is_resumed_only_by_the_same_commit(tmp_path, monkeypatch):
    """A resumed bench run keeps its finished frames as the code that wrote them made them: the work folder is kept
    for the same settings and commit, and cleared for another commit or a checkout with uncommitted changes."""
    import leovr.bench.real as real

    work = tmp_path / "real_work"
    commits = iter(["abc", "abc", "abd", "abd-dirty", "abd-dirty"])
    monkeypatch.setattr(real, "git_commit", lambda: next(commits))

    def kept_after_prepare() -> bool:
        real.prepared_work(work, {"window": 4})
        kept = (work / "finished").exists()
        (work / "finished").write_text("a run")
        return kept

    assert not kept_after_prepare()  # a new folder
    assert kept_after_prepare()  # the same commit: resumed
    assert not kept_after_prepare()  # another commit: afresh
    assert not kept_after_prepare()  # uncommitted changes: afresh
    assert not kept_after_prepare()  # ... every time
