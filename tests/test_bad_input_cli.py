"""Bad input through the command line, one row per class: exit code 2, a one-line error naming the
file or option, no traceback, and no partial output left behind."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import write_kitti_raw

from leovr.paths import REPO_ROOT


def _calib(drive: Path, text: str) -> None:
    (drive.parent / "calib_cam_to_cam.txt").write_text(text)


def _nan_checkpoint(path: Path) -> Path:
    import torch

    from leovr.paths import shipped_checkpoint

    state = torch.load(shipped_checkpoint(), map_location="cpu", weights_only=False)
    for k, v in state["model"].items():
        if v.is_floating_point():
            state["model"][k] = torch.full_like(v, float("nan"))
            break
    torch.save(state, path)
    return path


def _native(drive: Path, tmp: Path, edit) -> list[str]:
    """The drive converted to the native format, then broken by `edit(folder)`."""
    from leovr.data import open_sequence, write_native

    out = tmp / "native"
    write_native(open_sequence(drive), out)
    edit(out)
    return [str(out)]


def _nan_K(folder: Path) -> None:
    import yaml

    meta = yaml.safe_load((folder / "sequence.yaml").read_text())
    meta["camera"]["K"][0][0] = float("nan")
    (folder / "sequence.yaml").write_text(yaml.safe_dump(meta))


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _write_bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _yaml_value(folder: Path, line: str, new: str) -> None:
    y = folder / "sequence.yaml"
    y.write_text(y.read_text().replace(line, new))


EYE = "1 0 0 0 1 0 0 0 1"
# (id, how to break the drive -> extra args, command, what the message must name)
ROWS = [
    ("missing sequence", lambda d, t: [str(t / "nope")], "info", "nope: "),
    (
        "P_rect_02 of 9 numbers",
        lambda d, t: (_calib(d, f"P_rect_02: {EYE}\nR_rect_00: {EYE}\n"), [str(d)])[1],
        "info",
        "calib_cam_to_cam.txt: missing or malformed 'P_rect_02'",
    ),
    (
        "R_rect_00 of 12 numbers",
        lambda d, t: (_calib(d, f"P_rect_02: 100 0 40 0 0 100 30 0 0 0 1 0\nR_rect_00: {EYE} 0 0 0\n"), [str(d)])[1],
        "info",
        "'R_rect_00': needs 9 numbers",
    ),
    (
        "singular projection",
        lambda d, t: (_calib(d, f"P_rect_02: {' '.join(['0'] * 12)}\nR_rect_00: {EYE}\n"), [str(d)])[1],
        "info",
        "'P_rect_02' is singular",
    ),
    (
        "NaN projection",
        lambda d, t: (_calib(d, f"P_rect_02: nan 0 40 0 0 100 30 0 0 0 1 0\nR_rect_00: {EYE}\n"), [str(d)])[1],
        "info",
        "'P_rect_02' holds NaN",
    ),
    (
        "corrupt scan size",
        lambda d, t: ((d / "velodyne_points/data/0000000001.bin").write_bytes(b"\0" * 18), [str(d)])[1],
        "complete",
        "0000000001.bin: size 18 bytes",
    ),
    (
        "image of another size",
        lambda d, t: (cv2.imwrite(str(d / "image_02/data/0000000001.png"), np.zeros((40, 60, 3), np.uint8)), [str(d)])[
            1
        ],
        "complete",
        "0000000001.png: image is 60x40 but frame 0",
    ),
    (
        "output path is a file",
        lambda d, t: ((t / "f").write_text("x"), [str(d), "--out", str(t / "f")])[1],
        "complete",
        "f: output path is a file",
    ),
    (
        "NaN checkpoint",
        lambda d, t: [str(d), "--method", "generator", "--checkpoint", str(_nan_checkpoint(t / "nan.pt"))],
        "complete",
        "nan.pt: 1 weight tensors hold NaN",
    ),
    (
        "non-numeric sequence.yaml",
        lambda d, t: _native(d, t, lambda f: _yaml_value(f, "rate_hz: 10.0", "rate_hz: fast")),
        "info",
        "sequence.yaml: 'rate_hz' must be a positive number, not 'fast'",
    ),
    (
        "NaN in a poses file",
        lambda d, t: _native(
            d, t, lambda f: (f / "poses_tum.txt").write_text("0 0 0 0 0 0 0 1\n0.1 nan 0 0 0 0 0 1\n")
        ),
        "info",
        "poses_tum.txt: line 2 holds NaN",
    ),
    ("unknown input option", lambda d, t: [str(d), "--input", "vlp99"], "complete", "vlp99"),
    (
        "convert into a file",
        lambda d, t: ((t / "f").write_text("x"), [str(d), "--out", str(t / "f")])[1],
        "convert",
        "f: output path is a file",
    ),
    (
        "simulate into a file",
        lambda d, t: ((t / "f").write_text("x"), ["--out", str(t / "f"), "--frames", "2"])[1],
        "simulate",
        "f: output path is a file",
    ),
    (
        "viz into a folder",
        lambda d, t: ((t / "r.rrd").mkdir(), [str(d), "--out", str(t / "r.rrd")])[1],
        "viz",
        "r.rrd: output path is a folder",
    ),
    (
        "refine recording under a file",
        lambda d, t: ((t / "f").write_text("x"), [str(d), "--out", str(t / "o"), "--rerun", str(t / "f" / "r.rrd")])[1],
        "refine",
        "which is a file",
    ),
    (
        "self-supervised training into a file",
        lambda d, t: ((t / "f").write_text("x"), [str(d), "--mode", "selfsup", "--out", str(t / "f")])[1],
        "train",
        "f: output path is a file",
    ),
    (
        "viz of an unfinished run",
        lambda d, t: (
            (t / "run").mkdir(),
            (t / "run" / "run.json").write_text("{}"),
            [str(t / "run"), "--out", str(t / "r.rrd")],
        )[2],
        "viz",
        "this run did not finish (no metrics.json or poses_kitti.txt yet)",
    ),
    (
        "negative seed",
        lambda d, t: [str(d), "--seed", "-1"],
        "complete",
        "seed: Input should be greater than or equal to 0",
    ),
    (
        "infinite speed",
        lambda d, t: ["--out", str(t / "s"), "--frames", "2", "--speed-kmh", "inf"],
        "simulate",
        "speed_kmh: Input should be a finite number",
    ),
    (
        "NaN camera matrix",
        lambda d, t: _native(d, t, _nan_K),
        "info",
        "sequence.yaml: 'K' holds NaN or infinite values",
    ),
    (
        "convert into a folder holding a sequence",
        lambda d, t: (_native(d, t, lambda f: None), [str(d), "--out", str(t / "native")])[1],
        "convert",
        "native: already holds a sequence",
    ),
    (
        "convert into an interrupted convert's folder",
        lambda d, t: (_native(d, t, lambda f: (f / "sequence.yaml").unlink()), [str(d), "--out", str(t / "native")])[1],
        "convert",
        "native: holds an unfinished sequence (no sequence.yaml: an interrupted write?)",
    ),
    (
        "distance bins out of order",
        lambda d, t: [str(d), "-c", str(_write(t / "c.yaml", "complete:\n  bins: [40, 20, 0]\n"))],
        "complete",
        "bins must be at least two increasing distances",
    ),
    (
        "batch name leaving --out",
        lambda d, t: [
            str(_write(t / "m.yaml", f"- {{path: {d}, name: ../escape}}\n")),
            "--out",
            str(t / "b"),
            "--job",
            "complete",
        ],
        "batch",
        "name '../escape' must be a plain folder name",
    ),
    (
        "native format from a newer leovr",
        lambda d, t: _native(d, t, lambda f: _yaml_value(f, "version: 1", "version: 99")),
        "info",
        "sequence.yaml: format version 99 is newer than this leovr reads (1)",
    ),
    (
        "native scan cut mid-point",
        lambda d, t: _native(d, t, lambda f: open(f / "lidar" / "000001.bin", "ab").write(b"\0" * 4)),
        "info",
        "000001.bin: size",
    ),
    (
        "CSV manifest row longer than its header",
        lambda d, t: [str(_write(t / "m.csv", f"path,end\n{d},2,extra\n")), "--out", str(t / "b"), "--job", "complete"],
        "batch",
        "m.csv: row 2 has 1 more cell(s) than the header's columns",
    ),
    ("negative first frame", lambda d, t: [str(d), "--start", "-2"], "complete", "start: Input should be greater"),
    (
        "config that is not UTF-8",
        lambda d, t: [str(d), "-c", str(_write_bytes(t / "c.yaml", b"# caf\xe9\ncomplete: {}\n"))],
        "complete",
        "c.yaml: not UTF-8 text (byte 5",
    ),
    (
        "invalid YAML config",
        lambda d, t: [str(d), "-c", str(_write(t / "c.yaml", "complete: [1, 2\n"))],
        "complete",
        "c.yaml: invalid YAML at line 2",
    ),
    (
        "outputs inside the input sequence",
        lambda d, t: (_native(d, t, lambda f: None), [str(t / "native"), "--out", str(t / "native" / "run")])[1],
        "refine",
        "native/run: lies inside the input sequence",
    ),
    (
        "simulate over a recorded sequence",
        lambda d, t: (_native(d, t, lambda f: None), ["--out", str(t / "native"), "--frames", "2"])[1],
        "simulate",
        "native: holds a recorded sequence, not an earlier rendering",
    ),
    (
        "self-supervised training on too few frames",
        lambda d, t: [str(d), "--mode", "selfsup", "--out", str(t / "a")],
        "train",
        "self-supervised training needs at least 3 frames, got 2",
    ),
    (
        "batch with a misspelt option",
        lambda d, t: [
            str(_write(t / "m.yaml", f"- {{path: {d}, ned: 2}}\n")),
            "--out",
            str(t / "b"),
            "--job",
            "complete",
        ],
        "batch",
        "nothing run: 2011_01_01_drive_0001_sync: ",
    ),
    (
        "map of an unfinished run",
        lambda d, t: (
            (t / "run").mkdir(),
            (t / "run" / "run.json").write_text("{}"),
            [str(t / "run"), "--out", str(t / "m")],
        )[2],
        "map",
        "run: this run did not finish (no metrics.json or poses_kitti.txt yet)",
    ),
    (
        "map of a sequence, not a run",
        lambda d, t: [str(d), "--out", str(t / "m")],
        "map",
        "not a leovr refine run (no metrics.json and poses_kitti.txt)",
    ),
    (
        "map of a missing folder",
        lambda d, t: [str(t / "nowhere"), "--out", str(t / "m")],
        "map",
        "nowhere: no such folder",
    ),
    (
        "corrupt metrics.json to viz",
        lambda d, t: (
            (t / "run").mkdir(),
            (t / "run" / "metrics.json").write_text("{oops"),
            (t / "run" / "poses_kitti.txt").write_text(" ".join(["0"] * 12) + "\n"),
            [str(t / "run"), "--out", str(t / "r.rrd")],
        )[3],
        "viz",
        "metrics.json: not readable JSON",
    ),
]


@pytest.mark.slow
@pytest.mark.parametrize("name,breaks,command,named", ROWS, ids=[r[0] for r in ROWS])
def test_bad_input_is_one_clear_line(tmp_path, name, breaks, command, named):
    drive = write_kitti_raw(tmp_path / "raw", frames=2)
    args = breaks(drive, tmp_path)
    if command == "complete" and "--out" not in args:
        args += ["--out", str(tmp_path / "out")]
    before = {p for p in tmp_path.rglob("*")}
    r = subprocess.run(
        [sys.executable, "-c", "from leovr.cli import main; main()", command, *args],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
    )
    assert r.returncode == 2, (r.returncode, r.stdout[-500:], r.stderr[-1500:])
    assert "Traceback" not in r.stderr and named in r.stderr, r.stderr[-1500:]
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:") or "Error" in ln]
    assert len(errors) == 1, r.stderr
    left = [p for p in set(tmp_path.rglob("*")) - before if p.is_file()]
    assert not [p for p in left if p.name.startswith(".") or p.suffix == ".part"], left  # no half-written file
    if name in (
        "corrupt scan size",
        "image of another size",
    ):  # found at frame 1: frame 0 stays, resumable, with its run.json
        assert sorted(p.name for p in left) == ["000000.png", "inputs.json", "run.json"]
    else:  # found before any work
        assert not left, left


def test_a_scan_of_one_point_is_named_in_a_warning(tmp_path):
    """A truncated scan is still a scan: the run goes on, but the user hears which file it was."""
    drive = write_kitti_raw(tmp_path / "raw", frames=2)
    np.array([[5.0, 0.0, 0.0, 1.0]], np.float32).tofile(drive / "velodyne_points/data/0000000001.bin")
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "complete",
            str(drive),
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
    )
    assert r.returncode == 0, r.stderr[-1500:]
    assert "0000000001.bin: only 1 valid point(s)" in r.stderr and "Traceback" not in r.stderr
    # one line each, `warning: ...`, not Python's format with its source location
    lines = [ln for ln in r.stderr.splitlines() if "0000000001.bin" in ln]
    assert lines and all(ln.startswith("warning: ") for ln in lines) and "UserWarning" not in r.stderr, r.stderr
