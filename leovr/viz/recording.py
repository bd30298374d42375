"""Write a Rerun recording (.rrd) of a sequence, or of a `leovr refine` run over its sequence, with a
`frame` timeline.

The first 3D view is framed on the trajectory and shows the trajectories (ground truth, KISS-ICP,
leovr), accepted loops as edges, the landmarks, the LiDAR input coloured by range and one depth cloud
(the refined depth, subsampled, up to `CLOUD_MAX_M`). Under the camera pinhole (logged once, static):
the image, the refined and generator depth and the error against ground truth as float images (metres
on hover; unknown ground truth left empty), shown in the 2D views and hidden in the 3D one. Per-frame
scalars (MAE per method, time per stage, landmarks, loops) go to a time-series view."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.io import read_depth_png, read_json_object
from leovr.data.kitti_common import read_kitti_poses
from leovr.data.run_folder import is_finished_run, read_run
from leovr.data.run_info import run_depth_scale, run_frame_png
from leovr.errors import DataError, brief
from leovr.geometry import back_project, invert_T, transform_points
from leovr.pipeline.completion import prepare_sample
from leovr.pipeline.refine_input import completion_config
from leovr.pipeline.refine_outputs import CPU, TIMED, WALL

COLOURS = {"ground_truth": (40, 200, 80), "leovr": (255, 140, 0), "kiss_icp": (60, 120, 255)}
LANDMARK_COLOUR = (0, 150, 170)  # dark cyan: visible on the dark and the light theme
DEPTH_RANGE_M = (0.0, 80.0)  # colour scale of every depth layer
ERROR_RANGE_M = (0.0, 5.0)
CLOUD_MAX_M, CLOUD_STEP = 80.0, 8  # the 3D depth cloud: refined depth up to 80 m, every 8th pixel each way
# what keeps a recording light (a real KITTI frame's share about a sixth): images as JPEG, depth layers at half the
# image's resolution in float16 (a viewer's panel is smaller than the image; hovering still reads metres), every
# 8th LiDAR return, and the map once, with at most MAP_TRIANGLES triangles
JPEG_QUALITY = 85
DEPTH_STEP = 2
LIDAR_STEP = 8
MAP_TRIANGLES = 400_000
HIDDEN_IN_3D = (
    "world/camera/image/depth_refined",
    "world/camera/image/depth_generator",
    "world/camera/image/depth_ground_truth",
    "world/camera/image/error",
)


def blueprint(track: np.ndarray | None = None) -> rrb.Blueprint:
    """3D world (framed on `track`, camera positions N x 3, when given) left; image, depths and error
    right; per-frame scalars below."""
    eye = None
    if track is not None and len(track):
        lo, hi = track.min(axis=0), track.max(axis=0)
        centre, size = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 20.0)
        # RDF axes: y points down, so "above and behind" the start is -y, -z
        eye = rrb.EyeControls3D(
            position=centre + np.array([0.0, -0.6, -0.8]) * size, look_target=centre, eye_up=[0.0, -1.0, 0.0]
        )
    image = "world/camera/image"
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(
                    origin="world",
                    name="world",
                    eye_controls=eye,
                    overrides={e: rrb.EntityBehavior(visible=False) for e in HIDDEN_IN_3D},
                ),
                rrb.Vertical(
                    rrb.Spatial2DView(origin=image, contents=["$origin/rgb"], name="image"),
                    rrb.Spatial2DView(
                        origin=image,
                        contents=["$origin/depth_refined", "$origin/depth_ground_truth"],
                        name="refined depth (m)",
                    ),
                    rrb.Spatial2DView(origin=image, contents=["$origin/depth_generator"], name="generator depth (m)"),
                    rrb.Spatial2DView(origin=image, contents=["$origin/error"], name="|refined - ground truth| (m)"),
                ),
                column_shares=[3, 2],
            ),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin="metrics/mae_m", name="MAE per frame (m)"),
                rrb.TimeSeriesView(origin="metrics/time_ms", name="time per stage (ms)"),
                rrb.TimeSeriesView(
                    origin="metrics",
                    contents=["$origin/landmarks_last_seen", "$origin/loop_closed"],
                    name="landmarks, loops",
                ),
            ),
            row_shares=[4, 1],
        ),
        collapse_panels=True,
    )


def _range_colours(d: np.ndarray, max_range: float = 80.0) -> np.ndarray:
    x = np.clip(d / max_range * 255, 0, 255).astype(np.uint8)
    return cv2.applyColorMap(x[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]


def _error_image(pred: np.ndarray, gt: np.ndarray) -> "rr.DepthImage":
    """|pred - gt| in metres where ground truth exists (dilated so sparse points show), 0 (drawn
    empty) elsewhere; a float image so hovering shows metres."""
    valid = gt > 0
    err = np.where(valid, np.maximum(np.abs(pred - gt), 1e-3), 0.0).astype(np.float32)
    if valid.mean() < 0.2:
        err = cv2.dilate(err, np.ones((3, 3), np.uint8))
    h, w = (err.shape[0] // DEPTH_STEP) * DEPTH_STEP, (err.shape[1] // DEPTH_STEP) * DEPTH_STEP
    # sparse errors stay
    err = err[:h, :w].reshape(h // DEPTH_STEP, DEPTH_STEP, w // DEPTH_STEP, DEPTH_STEP).max(axis=(1, 3))
    # 0 m: purple
    return rr.DepthImage(err.astype(np.float16), meter=1.0, colormap="viridis", depth_range=ERROR_RANGE_M)


def _depth_image(d: np.ndarray) -> "rr.DepthImage":
    """Metres at half resolution (float16: no 16-bit cap, hovering shows metres), 0 = unknown."""
    return rr.DepthImage(
        np.nan_to_num(d[::DEPTH_STEP, ::DEPTH_STEP], nan=0.0).astype(np.float16),
        meter=1.0,
        colormap="turbo",
        depth_range=DEPTH_RANGE_M,
    )


def _depth_cloud(d: np.ndarray, K: np.ndarray, T: np.ndarray) -> "rr.Points3D":
    """Every CLOUD_STEP-th pixel of a depth map with depth in (0, CLOUD_MAX_M], in the world, coloured by depth."""
    v, u = np.mgrid[0 : d.shape[0] : CLOUD_STEP, 0 : d.shape[1] : CLOUD_STEP]
    z = d[v, u]
    keep = (z > 0) & (z <= CLOUD_MAX_M)
    uv = np.stack([u[keep], v[keep]], 1).astype(float)
    pts = transform_points(T, back_project(uv, z[keep].astype(float), K))
    return rr.Points3D(pts.astype(np.float32), colors=_range_colours(z[keep], CLOUD_MAX_M), radii=0.03)


def write_recording(target: str | Path, out: str | Path, max_frames: int | None = None) -> dict:
    """`target` is a refine run folder (with metrics.json) or a sequence folder. Returns a summary."""
    target, out = Path(target), Path(out)
    if is_finished_run(target) or (target / "run.json").is_file():
        r = read_run(target)
        run, seq, poses, indices = r.path, r.seq, r.poses, r.indices
    else:
        run, seq, poses = None, open_sequence(target), None
        indices = list(range(len(seq)))
    if max_frames is not None:
        indices = indices[:max_frames]
    if not indices:
        raise DataError(target, "nothing to record")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    try:
        strips = _record(tmp, run, seq, poses, indices)
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)  # a failed recording leaves nothing behind
    return {"frames": len(indices), "trajectories": sorted(strips), "path": str(out)}


def _array(path: Path) -> np.ndarray:
    """A run's .npy file, one clear error when it is truncated or not a NumPy array."""
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise DataError(path, f"unreadable NumPy file (truncated?): {exc}") from exc


def _json_field(path: Path, key: str):
    doc = read_json_object(path)
    if key not in doc:
        raise DataError(path, f"has no '{key}' field")
    return doc[key]


def _record(tmp: Path, run: Path | None, seq, poses: np.ndarray | None, indices: list[int]) -> dict:
    """Log everything into the recording file `tmp`; returns the trajectory strips logged."""
    rec = rr.RecordingStream("leovr")
    rec.save(tmp, default_blueprint=blueprint(poses[: len(indices), :3, 3] if poses is not None else None))
    try:
        strips = _log_all(rec, run, seq, poses, indices)
        rec.flush()
    finally:
        rec.disconnect()
    return strips


def _log_all(rec: "rr.RecordingStream", run: Path | None, seq, poses: np.ndarray | None, indices: list[int]) -> dict:
    rec.log("world", rr.ViewCoordinates.RDF, static=True)  # the first camera's axes: x right, y down, z forward
    strips = {}
    if poses is not None:
        strips["leovr"] = poses[: len(indices), :3, 3]
    icp = run / "poses_kiss_icp_kitti.txt" if run is not None else None
    if icp is not None and icp.is_file() and len(baseline := read_kitti_poses(icp)) >= len(indices):
        strips["kiss_icp"] = baseline[: len(indices), :3, 3]  # KISS-ICP alone on the run's input
    if run is not None and poses is not None and (run / "loops.json").is_file():
        at = {i: n for n, i in enumerate(indices)}
        pairs = [
            (at[r["frame"]], at[r["candidate"]])
            for r in _json_field(run / "loops.json", "loops")
            if r["accepted"] and r["frame"] in at and r["candidate"] in at
        ]
        if pairs:
            rec.log(
                "world/loops",
                rr.LineStrips3D([poses[[a, b], :3, 3] for a, b in pairs], colors=[(220, 40, 200)], radii=0.1),
                static=True,
            )
    if run is not None and (run / "landmarks.npy").is_file():
        rec.log(
            "world/landmarks",
            rr.Points3D(_array(run / "landmarks.npy"), colors=[LANDMARK_COLOUR], radii=0.06),
            static=True,
        )
    if run is not None and (run / "map" / "map.ply").is_file():
        rec.log("world/map", _map_mesh(run / "map" / "map.ply"), static=True)
    first = seq[indices[0]]
    rec.log(
        "world/camera/image",
        rr.Pinhole(
            image_from_camera=first.K,
            resolution=[first.width, first.height],
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=2.0,
        ),
        static=True,
    )
    scalars = _frame_scalars(run, indices)
    held_out = _held_out_truth(run, seq)
    scale = run_depth_scale(run) if run is not None else None
    folders = {"generator": "depth_generator", "refined": "depth"}
    gt: list[np.ndarray] = []  # ground-truth positions relative to the first camera, while every frame has one
    T0_inv = None
    missing = [i for i in indices if run is not None and not run_frame_png(run, "depth", i).is_file()]
    if missing:
        warnings.warn(
            f"{run / 'depth'}: no refined depth for {len(missing)} of the run's frames "
            f"({brief(missing)}); they are recorded without it",
            stacklevel=2,
        )
    for n, i in enumerate(indices):
        f = seq[i]
        rec.set_time("frame", sequence=i)
        if f.T_world_cam is not None and (n == 0 or T0_inv is not None):
            T0_inv = invert_T(f.T_world_cam) if n == 0 else T0_inv
            gt.append(T0_inv @ f.T_world_cam)
        else:
            T0_inv = None
        T = poses[n] if poses is not None else (gt[n] if T0_inv is not None else np.eye(4))
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        rec.log("world/camera/image/rgb", rr.Image(f.image).compress(jpeg_quality=JPEG_QUALITY))
        if f.points is not None and len(f.points):
            pts = f.points[::LIDAR_STEP, :3]
            rec.log(
                "world/lidar",
                rr.Points3D(
                    transform_points(T, transform_points(f.T_cam_lidar, pts)).astype(np.float32),
                    colors=_range_colours(np.linalg.norm(pts, axis=1)),
                    radii=0.04,
                ),
            )
        ref = f.depth if f.depth is not None else (held_out(f) if held_out is not None else None)
        for kind, folder in folders.items():
            png = run_frame_png(run, folder, i) if run is not None else None
            if png is None or not png.is_file():
                continue
            d = read_depth_png(png, scale, f.shape)
            rec.log(f"world/camera/image/depth_{kind}", _depth_image(d))
            if kind == "refined":
                rec.log("world/depth_cloud", _depth_cloud(d, f.K, T))
            if ref is not None and (ref > 0).any():
                rec.log(f"metrics/mae_m/{kind}", rr.Scalars(float(np.abs(d - ref)[ref > 0].mean())))
                if kind == "refined":
                    rec.log("world/camera/image/error", _error_image(d, ref))
        for name, value in scalars.get(i, {}).items():
            rec.log(f"metrics/{name}", rr.Scalars(value))
        if run is None and f.depth is not None:
            rec.log("world/camera/image/depth_ground_truth", _depth_image(f.depth))
    if T0_inv is not None:
        strips["ground_truth"] = np.stack([T[:3, 3] for T in gt])
    for name, xyz in strips.items():
        rec.log(f"world/trajectory/{name}", rr.LineStrips3D([xyz], colors=[COLOURS[name]], radii=0.08), static=True)
    return strips


def _map_mesh(path: Path) -> "rr.Mesh3D":
    """The run's map (`leovr map` / `refine --map`), decimated to at most MAP_TRIANGLES triangles."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    if not len(mesh.triangles):
        raise DataError(path, "unreadable or empty mesh")
    if len(mesh.triangles) > MAP_TRIANGLES:
        mesh = mesh.simplify_quadric_decimation(MAP_TRIANGLES)
    colours = (np.asarray(mesh.vertex_colors) * 255).astype(np.uint8) if mesh.has_vertex_colors() else None
    return rr.Mesh3D(
        vertex_positions=np.asarray(mesh.vertices, np.float32),
        triangle_indices=np.asarray(mesh.triangles, np.uint32),
        vertex_colors=colours,
    )


def _frame_scalars(run: Path | None, indices: list[int]) -> dict[int, dict[str, float]]:
    """Per frame: time per stage (timing.json's series), landmarks last seen there, accepted loops."""
    out: dict[int, dict[str, float]] = {i: {} for i in indices}
    if run is None:
        return out
    if (run / "timing.json").is_file():
        series = read_json_object(run / "timing.json").get("series", {})
        for k, name in enumerate(series.get("frame", [])):
            for stage in (*TIMED, WALL, CPU):  # the stages, the frame's end-to-end and CPU time (none in old runs)
                if name in out and stage in series and series[stage][k] is not None:
                    out[name][f"time_ms/{stage}"] = float(series[stage][k])
    if (run / "landmarks_frame.npy").is_file():
        seen = _array(run / "landmarks_frame.npy")
        counts = np.bincount(seen[seen >= 0], minlength=max(indices) + 1) if len(indices) else []
        for i in indices:
            out[i]["landmarks_last_seen"] = float(counts[i])
    if (run / "loops.json").is_file():
        for r in _json_field(run / "loops.json", "loops"):
            if r.get("accepted") and r.get("frame") in out:
                out[r["frame"]]["loop_closed"] = 1.0
    return out


def _held_out_truth(run: Path | None, seq):
    """For a refine run that held LiDAR points out (`--input vlp16|mid40|ratio:R`): Frame -> the
    held-out depth it was scored on, rebuilt from the settings in run.json; None otherwise."""
    if run is None or not (run / "run.json").is_file() or not seq.has_lidar:
        return None
    settings = (read_json_object(run / "run.json").get("identity") or {}).get("settings")
    if not isinstance(settings, dict) or settings.get("input", "full") == "full":
        return None
    try:
        ccfg = completion_config(RefineConfig(**settings))
    except ValueError:  # settings of another leovr version: no error layer rather than a wrong one
        return None

    def truth(frame) -> np.ndarray | None:
        sample = prepare_sample(frame, ccfg)  # the frame already loaded, as refine scores it
        return sample.gt if sample.gt_kind == "heldout" else None

    return truth
