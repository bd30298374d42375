"""Rerun recordings, read back with Rerun's own reader: entities and frame count."""

from __future__ import annotations

import json

import pyarrow.compute as pc
import pytest
import rerun as rr

from leovr.config import MapConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.errors import DataError
from leovr.pipeline.refine import run_refine
from leovr.pipeline.tsdf_map import map_run
from leovr.sim.simulate import simulate
from leovr.viz.recording import write_recording


def _read(path, timed=None):
    """Entities and frame numbers of a recording; `timed` (if given) collects the entities logged on the
    frame timeline, and the column names of each entity."""
    entities, frames = set(), set()
    for chunk in rr.chunk.RrdReader(path).stream():
        entities.add(str(chunk.entity_path))
        if timed is not None:
            timed.setdefault(str(chunk.entity_path), set()).update(chunk.to_record_batch().schema.names)
        if "frame" in chunk.timeline_names:
            col = chunk.to_record_batch().column("frame")
            frames.update(int(x) for x in pc.cast(col, "int64").to_pylist())
    return entities, frames


@pytest.mark.slow
def test_refine_run_recording_has_trajectories_depth_and_every_frame(tmp_path):
    simulate(SimulateConfig(lidar="mid40", frames=4, seed=7), tmp_path / "seq", progress=False)
    run_refine(open_sequence(tmp_path / "seq"), RefineConfig(input="full"), tmp_path / "run", progress=False)
    loop = {"frame": 3, "candidate": 0, "accepted": True}  # an accepted loop is drawn as an edge
    (tmp_path / "run" / "loops.json").write_text(json.dumps({"loops": [loop, {**loop, "frame": 2, "accepted": False}]}))
    map_run(tmp_path / "run", tmp_path / "run" / "map", MapConfig(), progress=False)  # the map goes in once
    summary = write_recording(tmp_path / "run", tmp_path / "r.rrd")
    assert summary["trajectories"] == ["ground_truth", "kiss_icp", "leovr"]
    columns: dict = {}
    entities, frames = _read(tmp_path / "r.rrd", columns)
    assert "frame" not in columns["/world/camera/image"]  # the pinhole is static, logged once
    assert "frame" not in columns["/world/map"] and any("Mesh3D" in c for c in columns["/world/map"])
    assert any("EncodedImage" in c for c in columns["/world/camera/image/rgb"])  # JPEG, not raw pixels
    assert any("DepthImage" in c for c in columns["/world/camera/image/error"])  # metres, not RGB
    for e in (
        "/world/trajectory/ground_truth",
        "/world/trajectory/leovr",
        "/world/trajectory/kiss_icp",
        "/world/landmarks",
        "/world/camera",
        "/world/camera/image",
        "/world/camera/image/rgb",
        "/world/camera/image/depth_generator",
        "/world/camera/image/depth_refined",
        "/world/camera/image/error",
        "/world/depth_cloud",
        "/world/lidar",
        "/world/loops",
        "/metrics/mae_m/refined",
        "/metrics/mae_m/generator",
        "/metrics/time_ms/graph_ms",
        "/metrics/time_ms/wall_ms",
        "/metrics/landmarks_last_seen",
        "/metrics/loop_closed",
    ):
        assert e in entities, e
    assert frames == {0, 1, 2, 3}
    assert not (tmp_path / "r.rrd.part").exists()
    # a corrupt run file fails with its name, before or during logging, and leaves neither the
    # recording nor a .part file behind
    for name, text in [("loops.json", '{"loops": [{"frame": 3}'), ("metrics.json", "[1, 2]")]:
        good = (tmp_path / "run" / name).read_text()
        (tmp_path / "run" / name).write_text(text)
        with pytest.raises(DataError, match=name.replace(".", r"\.")):
            write_recording(tmp_path / "run", tmp_path / "bad.rrd")
        assert not (tmp_path / "bad.rrd").exists() and not (tmp_path / "bad.rrd.part").exists()
        (tmp_path / "run" / name).write_text(good)
    # a finished run missing a frame's refined depth is recorded with a warning naming the frames
    png = tmp_path / "run" / "depth" / "000002.png"
    kept = png.read_bytes()
    png.unlink()
    with pytest.warns(UserWarning, match=r"no refined depth for 1 of the run's frames \(2\)"):
        write_recording(tmp_path / "run", tmp_path / "r2.rrd")
    png.write_bytes(kept)
    # a pose file shorter than the run's frames (an edit, a partial copy) is named, not an IndexError
    poses = tmp_path / "run" / "poses_kitti.txt"
    poses.write_text("".join(poses.read_text().splitlines(keepends=True)[:2]))
    with pytest.raises(DataError, match=r"poses_kitti\.txt: 2 poses for the run's 4 frames"):
        write_recording(tmp_path / "run", tmp_path / "bad.rrd")


def test_sequence_recording_without_a_run(tmp_path):
    simulate(SimulateConfig(lidar="vlp16", frames=2, seed=8), tmp_path / "seq", progress=False)
    write_recording(tmp_path / "seq", tmp_path / "s.rrd")
    entities, frames = _read(tmp_path / "s.rrd")
    assert "/world/camera/image/depth_ground_truth" in entities and frames == {0, 1}


def test_a_run_made_from_a_relative_path_is_found_from_another_folder(tmp_path, monkeypatch):
    """`leovr demo` ran from the repository root records `runs/demo/sequence`; viz run from elsewhere
    still finds it (looked up from the folders above the run)."""
    simulate(SimulateConfig(lidar="mid40", frames=2, seed=9), tmp_path / "runs" / "seq", progress=False)
    monkeypatch.chdir(tmp_path)
    run_refine(open_sequence("runs/seq"), RefineConfig(input="full"), tmp_path / "runs" / "run", progress=False)
    m = json.loads((tmp_path / "runs" / "run" / "metrics.json").read_text())
    assert m["sequence"] == str((tmp_path / "runs" / "seq").resolve())  # recorded absolute from now on
    m["sequence"] = "runs/seq"  # as older runs recorded it
    (tmp_path / "runs" / "run" / "metrics.json").write_text(json.dumps(m))
    monkeypatch.chdir(tmp_path / "runs" / "run")
    assert write_recording(tmp_path / "runs" / "run", tmp_path / "r.rrd")["frames"] == 2
