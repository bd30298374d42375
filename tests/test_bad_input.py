"""Bad input fails with a clear message naming the file (or is dropped with a warning)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import ring_scan, write_kitti_raw

from leovr.data import open_sequence
from leovr.errors import DataError


def test_missing_calibration_names_the_file(kitti_raw_tiny):
    (kitti_raw_tiny.parent / "calib_velo_to_cam.txt").unlink()
    with pytest.raises(DataError, match=r"calib_velo_to_cam\.txt: missing LiDAR-to-camera calibration"):
        open_sequence(kitti_raw_tiny)


def test_malformed_calibration_names_key_and_file(kitti_raw_tiny):
    (kitti_raw_tiny.parent / "calib_cam_to_cam.txt").write_text("P_rect_02: 1 2 3\nR_rect_00: 1 0 0 0 1 0 0 0 1\n")
    with pytest.raises(DataError, match=r"calib_cam_to_cam\.txt: missing or malformed 'P_rect_02'"):
        open_sequence(kitti_raw_tiny)
    (kitti_raw_tiny.parent / "calib_cam_to_cam.txt").write_text("P_rect_02: 1 2 x\n")
    with pytest.raises(DataError, match=r"calib_cam_to_cam\.txt: line 1"):
        open_sequence(kitti_raw_tiny)


def test_corrupt_image_names_the_file(kitti_raw_tiny):
    bad = kitti_raw_tiny / "image_02" / "data" / "0000000001.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n not really a png")
    seq = open_sequence(kitti_raw_tiny)
    seq[0]  # other frames still load
    with pytest.raises(DataError, match=r"0000000001\.png: corrupt"):
        seq[1]


def test_bin_size_not_multiple_of_16(kitti_raw_tiny):
    f = kitti_raw_tiny / "velodyne_points" / "data" / "0000000002.bin"
    f.write_bytes(f.read_bytes()[:-6])
    with pytest.raises(DataError, match=r"0000000002\.bin: size \d+ bytes is not a multiple of 16"):
        open_sequence(kitti_raw_tiny)[2]


def test_nan_and_inf_points_are_dropped_with_warning(kitti_raw_tiny):
    pts = ring_scan()
    pts[[3, 10], 0] = np.nan
    pts[20, 2] = np.inf
    pts.tofile(kitti_raw_tiny / "velodyne_points" / "data" / "0000000000.bin")
    with pytest.warns(UserWarning, match=r"0000000000\.bin: dropped 3 NaN or infinite points"):
        f = open_sequence(kitti_raw_tiny)[0]
    assert len(f.points) == len(pts) - 3 and np.isfinite(f.points).all()


def test_an_empty_scan_is_a_frame_without_returns_and_its_file_is_named(kitti_raw_tiny):
    (kitti_raw_tiny / "velodyne_points" / "data" / "0000000001.bin").write_bytes(b"")
    with pytest.warns(UserWarning, match=r"0000000001\.bin: empty LiDAR scan .*no LiDAR return"):
        f = open_sequence(kitti_raw_tiny)[1]
    assert f.points.shape == (0, 4)


def test_frames_are_paired_by_number_not_by_position(tmp_path):
    """One image and a different scan missing: the others keep their own partners, the gap stays a
    gap in time, and the warning names the skipped frame numbers."""
    drive = write_kitti_raw(tmp_path / "raw", frames=5)
    (drive / "image_02" / "data" / "0000000001.png").unlink()
    (drive / "velodyne_points" / "data" / "0000000003.bin").unlink()
    with pytest.warns(UserWarning, match=r"skipped frame 1 without an image|skipped frame 3 without a scan") as w:
        seq = open_sequence(drive)
    text = str(w[0].message)
    assert "frame 3 without a scan" in text and "frame 1 without an image" in text
    assert seq.frame_numbers() == [0, 2, 4] and len(seq) == 3
    assert (
        [p.stem for p in seq.image_files]
        == [p.stem for p in seq.scan_files]
        == ["0000000000", "0000000002", "0000000004"]
    )
    assert np.allclose(seq.timestamps(), [0.0, 0.2, 0.4])
    assert seq[1:].frame_numbers() == [2, 4]


def test_outputs_are_named_by_the_recordings_frame_numbers(tmp_path):
    """With frames 1 and 3 missing, refine writes 000000/000002/000004.png (the drive's numbers, not
    positions), TUM poses at the real times, and reads its own files back by number on resume."""
    import warnings

    from leovr.config import RefineConfig
    from leovr.data.run_info import read_run_depth
    from leovr.pipeline.refine import run_refine

    drive = write_kitti_raw(tmp_path / "raw", frames=5)
    (drive / "image_02" / "data" / "0000000001.png").unlink()
    (drive / "velodyne_points" / "data" / "0000000003.bin").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seq = open_sequence(drive)
    out = tmp_path / "out"
    run_refine(seq, RefineConfig(input="vlp16"), out, progress=False)
    for folder in ("depth", "depth_generator", "depth_ipbasic"):
        assert sorted(p.name for p in (out / folder).glob("*.png")) == ["000000.png", "000002.png", "000004.png"]
    assert np.allclose(np.loadtxt(out / "poses_tum.txt")[:, 0], [0.0, 0.2, 0.4])
    assert json.loads((out / "run.json").read_text())["frame_numbers"] == [0, 2, 4]
    assert read_run_depth(out, "depth", 2).shape == seq[2].shape
    run_refine(seq, RefineConfig(input="vlp16"), out, resume=True, progress=False)  # all three found, none redone
    assert json.loads((out / "timing.json").read_text())["frames_timed"] == 3


def test_calibration_of_the_wrong_size_or_singular_names_key_and_file(kitti_raw_tiny):
    calib = kitti_raw_tiny.parent / "calib_cam_to_cam.txt"
    good = calib.read_text()
    eye = "1 0 0 0 1 0 0 0 1"
    for text, msg in [
        (f"P_rect_02: {eye}\nR_rect_00: {eye}\n", r"'P_rect_02': needs 12 numbers, 9 numbers"),
        (f"P_rect_02: 100 0 40 0 0 100 30 0 0 0 1 0\nR_rect_00: {eye} 0 0 0\n", r"'R_rect_00': needs 9 numbers, 12"),
        (f"P_rect_02: 0 0 0 0 0 0 0 0 0 0 0 0\nR_rect_00: {eye}\n", "singular"),
        (f"P_rect_02: nan 0 40 0 0 100 30 0 0 0 1 0\nR_rect_00: {eye}\n", "NaN"),
    ]:
        calib.write_text(text)
        with pytest.raises(DataError, match=r"calib_cam_to_cam\.txt: .*" + msg):
            open_sequence(kitti_raw_tiny)
    calib.write_text(good)
    open_sequence(kitti_raw_tiny)


def test_timestamps_going_backwards(kitti_raw_tiny):
    (kitti_raw_tiny / "image_02" / "timestamps.txt").write_text(
        "2011-09-26 13:02:25.100000000\n2011-09-26 13:02:25.200000000\n2011-09-26 13:02:25.150000000\n"
    )
    with pytest.raises(DataError, match=r"timestamps\.txt: timestamps go backwards .* at entry 2"):
        open_sequence(kitti_raw_tiny)


def test_native_description_errors(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "sequence.yaml").write_text("format: leovr-native\nframes: 1\ncamera: {K: [[1, 0], [0, 1]]}\n")
    with pytest.raises(DataError, match=r"sequence\.yaml: 'K' must be 3x3"):
        open_sequence(tmp_path)
    (tmp_path / "sequence.yaml").write_text("format: [unclosed\n")
    with pytest.raises(DataError, match=r"sequence\.yaml: invalid YAML"):
        open_sequence(tmp_path)


def test_missing_folder_and_file_instead_of_folder(tmp_path):
    with pytest.raises(DataError, match="no such file or folder"):
        open_sequence(tmp_path / "nope")
    (tmp_path / "f.txt").write_text("x")
    with pytest.raises(DataError, match="a sequence is a folder"):
        open_sequence(tmp_path / "f.txt")


def test_checkpoint_with_nan_weights_is_refused(tmp_path):
    import torch

    from leovr.depth.inference import load_generator
    from leovr.paths import shipped_checkpoint

    state = torch.load(shipped_checkpoint(), map_location="cpu", weights_only=False)
    key = next(k for k, v in state["model"].items() if v.is_floating_point())
    state["model"][key] = torch.full_like(state["model"][key], float("nan"))
    torch.save(state, tmp_path / "nan.pt")
    with pytest.raises(DataError, match=r"nan\.pt: 1 weight tensors hold NaN"):
        load_generator(tmp_path / "nan.pt")


def test_depth_png_of_another_size_names_file_and_sizes(tmp_path):
    import cv2

    from leovr.data.io import read_depth_png, write_depth_png
    from leovr.data.run_info import read_run_depth, write_run_info

    write_run_info(tmp_path, "complete")
    write_depth_png(tmp_path / "depth" / "000003.png", np.full((20, 30), 5.0))
    assert read_run_depth(tmp_path, "depth", 3, (20, 30)).max() == 5.0
    with pytest.raises(DataError, match=r"000003\.png: depth image is 30x20, the frame is 40x10"):
        read_run_depth(tmp_path, "depth", 3, (10, 40))
    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DataError, match=r"rgb\.png: depth image must be single-channel uint16"):
        read_depth_png(tmp_path / "rgb.png")


def test_a_resume_after_an_input_was_edited_in_place_is_refused_naming_the_file(tmp_path):
    """The recording's fingerprint is its files' contents, not their names and sizes: one scan edited in place
    (same size) between a run and its resume refuses the resume and names the scan."""
    from leovr.config import RefineConfig
    from leovr.pipeline.refine import run_refine

    drive = write_kitti_raw(tmp_path / "raw", frames=3)
    out = tmp_path / "out"
    run_refine(open_sequence(drive), RefineConfig(input="vlp16"), out, progress=False, score=False)
    scan = drive / "velodyne_points" / "data" / "0000000001.bin"
    size = scan.stat().st_size
    points = np.fromfile(scan, np.float32)
    points[0] += 0.5
    points.tofile(scan)
    assert scan.stat().st_size == size
    with pytest.raises(DataError, match=r"contents_sha1.*0000000001\.bin \(changed\)"):
        run_refine(open_sequence(drive), RefineConfig(input="vlp16"), out, resume=True, progress=False, score=False)
    run_refine(open_sequence(drive), RefineConfig(input="vlp16"), tmp_path / "fresh", progress=False, score=False)


@pytest.mark.parametrize("poses", ['{"0": [1, 2, 3]}', '{"0": [NaN, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}'])
def test_a_tampered_progress_file_is_refused_naming_it(tmp_path, poses):
    """A resume reads back the finished frames' poses: one that is not 16 finite numbers is refused, not
    written into the outputs (NaN) or failed on deep in the pipeline."""
    from leovr.pipeline.refine_outputs import Progress

    path = tmp_path / "progress.json"
    path.write_text('{"poses": %s, "icp_poses": {}, "sources": {}, "times": {}}' % poses)
    with pytest.raises(DataError, match=r"progress\.json: cannot resume from this progress file: poses of frame 0"):
        Progress.load(path)
    path.write_text("[1, 2]")
    with pytest.raises(DataError, match="not a JSON object"):
        Progress.load(path)


def test_a_progress_file_with_a_broken_step_covariance_is_refused_naming_it(tmp_path):
    """The window's step covariances feed loop closure's pose graph after a resume: one that is not 36 finite
    numbers is refused with the file named."""
    from leovr.pipeline.refine_outputs import Progress

    path = tmp_path / "progress.json"
    path.write_text('{"poses": {}, "icp_poses": {}, "sources": {}, "times": {}, "step_covariances": {"3": [1, 2]}}')
    with pytest.raises(DataError, match=r"progress\.json: .*step_covariances of frame 3 is not 36 finite numbers"):
        Progress.load(path)


def test_simulate_replaces_an_earlier_rendering_and_convert_refuses_to_mix(tmp_path):
    """Rendering again into a folder replaces the earlier sequence (no frame of it is left); converting into a
    folder that holds a sequence is refused."""
    from leovr.config import SimulateConfig
    from leovr.data import write_native
    from leovr.sim.simulate import simulate

    simulate(SimulateConfig(lidar="vlp16", frames=3, seed=5), tmp_path / "s", progress=False)
    simulate(SimulateConfig(lidar="vlp16", frames=2, seed=5), tmp_path / "s", progress=False)
    assert len(open_sequence(tmp_path / "s")) == 2 and len(list((tmp_path / "s" / "images").iterdir())) == 2
    with pytest.raises(DataError, match="already holds a sequence"):
        write_native(open_sequence(tmp_path / "s"), tmp_path / "s")
    # an interrupted convert (frames on disk, no sequence.yaml) is named as such; overwrite replaces it whole
    (tmp_path / "s" / "sequence.yaml").unlink()
    src = (
        simulate(SimulateConfig(lidar="vlp16", frames=1, seed=6), tmp_path / "one", progress=False) and tmp_path / "one"
    )
    with pytest.raises(DataError, match="unfinished sequence"):
        write_native(open_sequence(src), tmp_path / "s")
    write_native(open_sequence(src), tmp_path / "s", overwrite=True)
    assert len(open_sequence(tmp_path / "s")) == 1 and len(list((tmp_path / "s" / "images").iterdir())) == 1


def test_a_fresh_run_replaces_an_earlier_run_of_its_command_and_refuses_another_commands(tmp_path):
    """Run again without --resume into the same folder: nothing of the earlier run stays (a frame it had and this
    one has not); a folder holding another command's run is refused before any work."""
    from leovr.config import CompleteConfig, RefineConfig
    from leovr.pipeline.completion import run_completion
    from leovr.pipeline.refine import run_refine

    seq = open_sequence(write_kitti_raw(tmp_path / "raw", frames=4))
    out = tmp_path / "out"
    run_completion(seq, CompleteConfig(method="nearest", input="vlp16", end=3), out, progress=False)
    assert len(list((out / "depth").glob("*.png"))) == 3
    run_completion(seq, CompleteConfig(method="nearest", input="vlp16", end=2), out, progress=False)
    assert sorted(p.name for p in (out / "depth").glob("*.png")) == ["000000.png", "000001.png"]
    assert json.loads((out / "metrics.json").read_text())["frames"] == 2
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    with pytest.raises(DataError, match="holds a `complete` run; write the `refine` outputs to another folder"):
        run_refine(seq, RefineConfig(end=2), out, progress=False)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before
