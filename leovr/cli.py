"""The `leovr` command line: a thin layer over the library. Errors about data or configuration are
printed as one line naming the file and the problem, never as a traceback."""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path
from typing import Optional

import typer

from leovr.cli_bench import ConfigOpt, bench_app
from leovr.cli_jobs import batch, train
from leovr.config import MapConfig, load_config, override
from leovr.errors import LeovrError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="leovr: dense depth and drift-free poses from a camera and a cheap LiDAR.",
)
app.add_typer(bench_app, name="bench")


@app.callback()
def bag_topics(
    camera_topic: Optional[str] = typer.Option(
        None, help="ROS bags: the camera's image topic (default: the only one)."
    ),
    camera_info_topic: Optional[str] = typer.Option(None, help="ROS bags: the camera's CameraInfo topic."),
    lidar_topic: Optional[str] = typer.Option(None, help="ROS bags: the PointCloud2 topic (default: the only one)."),
    pose_topic: Optional[str] = typer.Option(None, help="ROS bags: ground-truth poses (Odometry or PoseStamped)."),
    extrinsic: Optional[Path] = typer.Option(None, help="ROS bags without /tf_static: T_cam_lidar, 12 or 16 numbers."),
    drop_unpaired: bool = typer.Option(False, help="ROS bags: leave out images without a scan within half a period."),
) -> None:
    """Options before the command apply to every ROS bag it reads: `leovr --lidar-topic /points refine BAG ...`."""
    from leovr.data import rosbag

    rosbag.CHOICE = rosbag.TopicChoice(
        camera_topic, camera_info_topic, lidar_topic, pose_topic, extrinsic, drop_unpaired
    )


@app.command()
def info(
    path: Path = typer.Argument(..., help="Sequence folder or ROS bag."),
    reader: Optional[str] = typer.Option(
        None, help="Force a reader: native, kitti_raw, kitti_odometry, tum_rgbd, rosbag."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
    frames: bool = typer.Option(False, "--frames", help="Also read every frame and report frames per second."),
) -> None:
    """Summarise a sequence: reader, frames, resolution, points per scan, poses / depth present; for a ROS
    bag its topics and what each is used for."""
    from leovr.data import open_sequence
    from leovr.data.summary import sequence_summary

    summary = sequence_summary(open_sequence(path, reader), read_frames=frames)
    if as_json:
        typer.echo(json.dumps(summary, indent=2))
        return
    topics = summary.pop("topics", None)
    width = max(len(k) for k in summary)
    for k, v in summary.items():
        if k.endswith("_s") and isinstance(v, list) and len(v) == 3:  # a bag's pairing offsets
            v = f"{v[0]} / {v[1]} / {v[2]} (min / median / max)"
        typer.echo(f"{k:<{width}}  {v}")
    if topics:
        w = [max(len(str(r[c])) for r in topics) for c in ("topic", "type", "messages")]
        for r in topics:
            typer.echo(
                f"  {r['topic']:<{w[0]}}  {r['type']:<{w[1]}}  {r['messages']:>{w[2]}} msgs  "
                f"{r['rate_hz']:6.2f} Hz  {r['used_as']}"
            )


@app.command()
def complete(
    seq: Path = typer.Argument(..., help="Sequence folder."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (depth/NNNNNN.png, metrics.json)."),
    method: Optional[str] = typer.Option(None, help="nearest | ipbasic | generator"),
    checkpoint: Optional[Path] = typer.Option(None, help="Generator weights (default: the shipped checkpoint)."),
    input: Optional[str] = typer.Option(None, "--input", help="Cheap input: vlp16 | mid40 | ratio:R | full"),
    seed: Optional[int] = typer.Option(None, help="Seed of the ratio input (the config's top-level seed)."),
    start: Optional[int] = typer.Option(None, help="First frame."),
    end: Optional[int] = typer.Option(None, help="Stop before this frame."),
    step: Optional[int] = typer.Option(None, help="Frame step."),
    resume: bool = typer.Option(False, help="Reuse depth PNGs already in OUT."),
    config: Optional[Path] = ConfigOpt,
) -> None:
    """Classical depth completion of a simulated cheap LiDAR input, scored on held-out points."""
    from leovr.data import open_sequence
    from leovr.pipeline.completion import run_completion

    cfg = override(
        override(load_config(config), seed=seed).complete,
        method=method,
        input=input,
        start=start,
        end=end,
        step=step,
        checkpoint=None if checkpoint is None else str(checkpoint),
    )
    m = run_completion(open_sequence(seq), cfg, out, resume=resume)
    if not m.get("n"):
        typer.echo(
            f"nothing scored: no held-out point fell inside the image ({m['frames']} frames) -> {out / 'metrics.json'}"
        )
        return
    typer.echo(
        f"MAE {m['mae_m']:.3f} m  RMSE {m['rmse_m']:.3f} m  delta1 {m['delta1']:.3f}  "
        f"({m['n']} points, {m['frames']} frames) -> {out / 'metrics.json'}"
    )


@app.command()
def convert(
    seq: Path = typer.Argument(..., help="Sequence folder or ROS bag in any supported layout."),
    out: Path = typer.Option(
        ...,
        "--out",
        "-o",
        help="Output folder in the native format, or a ROS bag: "
        "NAME.mcap or NAME.db3 (a ROS 2 bag folder NAME/), NAME.bag (ROS 1).",
    ),
    overwrite: bool = typer.Option(False, help="Replace a sequence (finished or interrupted) already in --out."),
) -> None:
    """Copy a sequence into leovr's native format (docs/formats.md), or write it as a ROS bag."""
    from leovr.data import open_sequence, write_native
    from leovr.data.io import check_output_dir
    from leovr.data.rosbag_writer import bag_format, write_bag

    source = open_sequence(seq)
    if bag_format(out) is not None:
        check_output_dir(out.parent)
        bag = write_bag(source, out)
        typer.echo(
            f"wrote {bag}"
            + (f" (a ROS 2 bag: {', '.join(sorted(p.name for p in bag.iterdir()))})" if bag.is_dir() else "")
        )
        return
    typer.echo(f"wrote {write_native(source, check_output_dir(out), overwrite=overwrite)}")


@app.command()
def simulate(
    out: Path = typer.Option(..., "--out", "-o", help="Output folder (native format)."),
    scenario: Optional[str] = typer.Option(None, help="city_loop | straight | dynamic | traffic"),
    lidar: Optional[str] = typer.Option(None, help="vlp16 | hdl64 | mid40"),
    frames: Optional[int] = typer.Option(None, help="Number of frames."),
    seed: Optional[int] = typer.Option(None, help="World and noise seed (the config's top-level seed)."),
    light: Optional[str] = typer.Option(None, help="day | dusk | night"),
    speed_kmh: Optional[float] = typer.Option(None, "--speed-kmh", help="Ego speed."),
    preview: bool = typer.Option(False, help="Also write preview.png (image, depth, LiDAR overlay)."),
    config: Optional[Path] = ConfigOpt,
) -> None:
    """Render a sequence of the procedural city: images, LiDAR, poses, dense depth, moving masks."""
    from leovr.data.io import check_output_dir
    from leovr.sim.simulate import simulate as run_simulate

    check_output_dir(out)
    cfg = override(
        override(load_config(config), seed=seed).simulate,
        scenario=scenario,
        lidar=lidar,
        frames=frames,
        light=light,
        speed_kmh=speed_kmh,
    )
    r = run_simulate(cfg, out, preview=preview)
    typer.echo(f"{cfg.frames} frames at {r['frames_per_s']:.1f} frames/s -> {out}")


@app.command()
def demo(
    out: Path = typer.Option(Path("runs/demo"), "--out", "-o", help="Output folder."),
    frames: Optional[int] = typer.Option(None, help="Number of frames."),
    data: Optional[Path] = typer.Option(None, help="A recorded sequence instead of the generated default."),
    config: Optional[Path] = ConfigOpt,
) -> None:
    """The main job on the embedded default: a generated Mid-40 drive refined end to end; report, plots, recording."""
    from leovr.pipeline.demo import run_demo

    cfg = override(load_config(config).demo, frames=frames, data=None if data is None else str(data))
    run_demo(out, cfg)
    typer.echo((out / "report.md").read_text())
    typer.echo(
        f"outputs in {out.resolve()}: report.md, metrics.json, mae_by_distance.png, trajectory.png, map.png, "
        "demo.rrd, refine/ (map in refine/map/)"
    )


@app.command()
def refine(
    data: Path = typer.Argument(..., help="Sequence folder (KITTI raw/odometry, TUM RGB-D or native)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    config: Optional[Path] = ConfigOpt,
    checkpoint: Optional[Path] = typer.Option(None, help="Generator weights (default: the shipped checkpoint)."),
    window: Optional[int] = typer.Option(None, help="Frames in the sliding window."),
    input: Optional[str] = typer.Option(
        None,
        "--input",
        help="LiDAR input: full (the recording's own scan, default), vlp16 | mid40 | ratio:R simulated from it, or "
        "none (camera only; the scan becomes ground truth).",
    ),
    start: Optional[int] = typer.Option(None),
    end: Optional[int] = typer.Option(None),
    resume: bool = typer.Option(False, help="Continue an interrupted run in OUT."),
    rerun: Optional[Path] = typer.Option(None, "--rerun", help="Also write a Rerun recording of the run (.rrd)."),
    loop_closure: Optional[bool] = typer.Option(
        None, "--loop-closure/--no-loop-closure", help="Close loops afterwards."
    ),
    causal: Optional[bool] = typer.Option(
        None, "--causal/--no-causal", help="Live use: each frame's outputs from it and earlier frames only."
    ),
    fuse_map: bool = typer.Option(False, "--map", help="Then fuse the run into a 3D map in OUT/map (as `leovr map`)."),
) -> None:
    """Generator depth refined with poses and landmarks in the sliding-window factor graph."""
    loaded = load_config(config)
    cfg = override(
        loaded.refine,
        checkpoint=None if checkpoint is None else str(checkpoint),
        window=window,
        input=input,
        start=start,
        end=end,
        loop={"enabled": loop_closure},
        causal=causal,
    )
    if fuse_map:
        from leovr.data.io import check_output_dir

        check_output_dir(out / "map")
    _run_refine(data, out, cfg, resume, rerun)
    if fuse_map:
        _echo_map(_fuse(out, out / "map", loaded.map))


def _fuse(run: Path, out: Path, cfg) -> dict:
    from leovr.pipeline.tsdf_map import map_run

    return map_run(run, out, cfg)


def _echo_map(r: dict) -> None:
    typer.echo(
        f"map: {r['frames']} frames, {r['triangles']} triangles, {r['seconds_per_frame'] * 1000:.0f} ms a frame, "
        f"peak memory {r['peak_memory_mb']:.0f} MB -> {Path(r['out'])}/map.ply, map_points.ply"
    )


@app.command("map")
def map_command(
    run: Path = typer.Argument(..., help="A finished `leovr refine` output folder."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder: map.ply (mesh), map_points.ply, map.json."),
    voxel: Optional[float] = typer.Option(None, help=f"Voxel edge in metres (default {MapConfig().voxel_m:g})."),
    max_depth: Optional[float] = typer.Option(
        None, "--max-depth", help=f"Leave out depth beyond this (m, default {MapConfig().max_depth_m:g})."
    ),
    sigma_max: Optional[float] = typer.Option(
        None, "--sigma-max", help="Leave out pixels whose predicted uncertainty exceeds this fraction of their depth."
    ),
    config: Optional[Path] = ConfigOpt,
) -> None:
    """Fuse a refine run's depth, images and poses into a TSDF map: a coloured mesh and point cloud."""
    from leovr.data.io import check_output_dir

    cfg = override(load_config(config).map, voxel_m=voxel, max_depth_m=max_depth, sigma_max=sigma_max)
    _echo_map(_fuse(run, check_output_dir(out), cfg))


@app.command()
def poses(
    data: Path = typer.Argument(..., help="Sequence folder."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    config: Optional[Path] = ConfigOpt,
    loop_closure: bool = typer.Option(True, "--loop-closure/--no-loop-closure", help="Close loops (default on)."),
    input: Optional[str] = typer.Option(
        None,
        "--input",
        help="LiDAR input: full (the recording's own scan, default), vlp16 | mid40 | ratio:R simulated from it, or "
        "none (camera only).",
    ),
    resume: bool = typer.Option(False, help="Continue an interrupted run in OUT."),
    compare: bool = typer.Option(
        False,
        "--compare",
        help="Also run the textbook monocular VO (mono_vo) and, with LiDAR, KISS-ICP alone (kiss_icp), and score "
        "them beside leovr.",
    ),
) -> None:
    """The offline pose pass the self-supervised trainer uses: window odometry, then loop closure."""
    cfg = override(load_config(config).refine, loop={"enabled": loop_closure}, input=input, compare=compare or None)
    _run_refine(data, out, cfg, resume, None)


def _run_refine(data: Path, out: Path, cfg, resume: bool, rerun: Optional[Path]) -> None:
    from leovr.data import open_sequence
    from leovr.data.io import check_output_file
    from leovr.pipeline.refine import run_refine

    if rerun is not None:
        check_output_file(rerun)
    seq = open_sequence(data)
    m = run_refine(seq, cfg, out, resume=resume)
    if cfg.loop.enabled:
        loops = json.loads((out / "loops.json").read_text())["loops"]
        typer.echo(f"loops: {sum(r['accepted'] for r in loops)} accepted of {len(loops)} candidates (loops.json)")
    typer.echo(m["mode"])
    for method, r in m["depth"].items():
        if r.get("n"):
            typer.echo(f"{method:15s} MAE {r['mae_m']:.3f} m  RMSE {r['rmse_m']:.3f} m  ({r['n']} points)")
    if not any(r.get("n") for r in m["depth"].values()):
        why = (
            "the whole scan is the input; --input vlp16|mid40|none holds points out"
            if m["input"] == "full"
            else "the sequence has neither ground-truth depth nor LiDAR"
        )
        typer.echo(f"depth not scored: no ground truth ({why})")
    for name, t in m.get("trajectory", {}).items():
        scale = f", scale {t['scale']:.3f}" if t["align"] == "sim3" else ""
        drift = (
            f"  KITTI {t['kitti_t_err_pct']:.2f} % {t['kitti_r_err_deg_per_m']:.4f} deg/m"
            if t.get("kitti_t_err_pct") is not None
            else ""
        )
        typer.echo(f"{name:9s} ATE {t['ate_m']:.3f} m  RPE {t['rpe_m']:.3f} m{drift} ({t['align']} aligned{scale})")
    t = m["timing"]
    wall = t["stats"].get("wall_ms", {}).get("median")
    cpu = t["stats"].get("cpu_ms", {}).get("median")
    typer.echo(
        f"per frame: generator {t['generator_ms']:.0f} ms, front end {t['frontend_ms']:.0f} ms, "
        f"graph {t['graph_ms']:.0f} ms, output {t['output_ms']:.0f} ms"
        + (f"; {wall:.0f} ms end to end (median; the generator runs beside the graph)" if wall else "")
        + (f", {cpu:.0f} ms of CPU time (all threads)" if cpu else "")
        + f" -> {out}"
    )
    if rerun is not None:
        from leovr.viz.recording import write_recording

        typer.echo(f"recording -> {write_recording(out, rerun)['path']}")


@app.command()
def viz(
    target: Path = typer.Argument(..., help="A `leovr refine` output folder or a sequence folder."),
    out: Path = typer.Option(..., "--out", "-o", help="Recording file (.rrd); open it with `rerun FILE.rrd`."),
    max_frames: Optional[int] = typer.Option(None, "--max-frames", min=1, help="Record the first N frames only."),
) -> None:
    """Write a Rerun recording: trajectories, landmarks, LiDAR, camera, image, depth maps and error."""
    from leovr.data.io import check_output_file
    from leovr.viz.recording import write_recording

    r = write_recording(target, check_output_file(out), max_frames)
    typer.echo(f"{r['frames']} frames, trajectories: {', '.join(r['trajectories']) or 'none'} -> {r['path']}")


app.command()(train)
app.command()(batch)


def _warning_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line, `warning: ...`, without Python's source location (users did nothing wrong
    in leovr's code)."""
    from tqdm import tqdm

    tqdm.write(f"warning: {message}", file=sys.stderr)  # above any progress bar, not inside its line


def main() -> None:
    """Console entry point: run the app, turning user-facing errors into one line and exit code 2, and
    warnings into one `warning: ...` line each."""
    warnings.showwarning = _warning_line
    try:
        app()
    except LeovrError as exc:
        typer.secho(f"error: {exc}", err=True, fg=typer.colors.RED)
        sys.exit(2)


if __name__ == "__main__":
    main()
