"""Depth PNGs in the KITTI depth-completion convention (metres x 256), and run folders that say so."""

from __future__ import annotations

import json

import numpy as np
import pytest

from leovr.data.io import read_depth_png, write_depth_png
from leovr.data.run_info import check_resumable, read_run_depth, run_depth_scale, write_run_info
from leovr.errors import DataError


def test_far_depth_survives_the_png(tmp_path):
    depth = np.array([[0.0, 1.2345, 65.6, 120.0, 255.9, np.nan]], np.float32)
    write_depth_png(tmp_path / "d.png", depth)
    back = read_depth_png(tmp_path / "d.png")
    np.testing.assert_allclose(back[0, 1:5], depth[0, 1:5], atol=0.5 / 256)  # no cut at 65.5 m
    assert back[0, 0] == 0 and back[0, 5] == 0  # unknown stays unknown


def test_run_folders_record_their_depth_scale(tmp_path):
    new, old = tmp_path / "new", tmp_path / "old"
    write_run_info(new, "refine")
    write_depth_png(new / "depth" / "000003.png", np.full((4, 5), 80.0, np.float32))
    assert json.loads((new / "run.json").read_text())["depth_png"]["scale"] == 256.0
    np.testing.assert_allclose(read_run_depth(new, "depth", 3), 80.0)
    # a folder from an older leovr: millimetre PNGs, no run.json
    write_depth_png(old / "depth" / "000003.png", np.full((4, 5), 12.5, np.float32), scale=1000.0)
    assert run_depth_scale(old) == 1000.0
    np.testing.assert_allclose(read_run_depth(old, "depth", 3), 12.5)
    check_resumable(new)
    with pytest.raises(DataError, match="older leovr"):
        check_resumable(old)
    (new / "run.json").write_text('{"depth_png": {"scale": -1}}')
    with pytest.raises(DataError, match="run.json"):
        run_depth_scale(new)


def test_a_frames_equal_maps_are_encoded_once_and_written_alike(tmp_path, monkeypatch):
    """A frame's depth maps go out as PNGs each; a map equal to an earlier one in PNG units (a spinning LiDAR's
    refined depth is its generator's) reuses that PNG: the same bytes as written on its own, one encoding less."""
    import leovr.pipeline.refine_outputs as outputs

    rng = np.random.default_rng(0)
    depth = rng.uniform(1.0, 80.0, (20, 30)).astype(np.float32)
    maps = {"depth_generator": depth, "depth": depth.astype(np.float64) * 1.0, "sigma": depth * 0.1}
    encoded = []
    encode = outputs.depth_png_bytes
    monkeypatch.setattr(outputs, "depth_png_bytes", lambda units, path: encoded.append(units) or encode(units, path))
    outputs.write_frame_files(tmp_path / "run", "000007.png", maps, tmp_path / "run" / "progress.json", "{}\n")
    assert len(encoded) == 2
    for folder, m in maps.items():
        write_depth_png(tmp_path / "alone" / folder / "000007.png", m)
        assert (tmp_path / "run" / folder / "000007.png").read_bytes() == (
            tmp_path / "alone" / folder / "000007.png"
        ).read_bytes()
    np.testing.assert_allclose(read_depth_png(tmp_path / "run" / "sigma" / "000007.png"), depth * 0.1, atol=0.5 / 256)
    assert (tmp_path / "run" / "progress.json").read_text() == "{}\n"
