"""Write a Rerun recording (.rrd) of a sequence, or of a `leovr refine` run over its sequence, with a
`frame` timeline: trajectories (ground truth, KISS-ICP, leovr) as line strips, accepted loops as edges, landmarks, the LiDAR
input coloured by range, and under the camera pinhole the image, generator and refined depth (uint16
depth images, so the viewer back-projects them) and the error map against ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from leovr.data import open_sequence
from leovr.data.io import read_json_object
from leovr.data.kitti_common import read_kitti_poses
from leovr.data.run_info import read_run_depth, run_frame_png
from leovr.errors import DataError
from leovr.geometry import invert_T, transform_points

COLOURS = {"ground_truth": (40, 200, 80), "leovr": (255, 140, 0), "kiss_icp": (60, 120, 255)}


def blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="world"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="world/camera/image", contents=["$origin/rgb"], name="image"),
                rrb.Spatial2DView(origin="world/camera/image", contents=["$origin/depth_refined"], name="refined depth"),
                rrb.Spatial2DView(origin="world/camera/image", contents=["$origin/depth_generator"], name="generator depth"),
                rrb.Spatial2DView(origin="world/camera/error", name="|error| vs ground truth"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _range_colours(d: np.ndarray, max_range: float = 80.0) -> np.ndarray:
    x = np.clip(d / max_range * 255, 0, 255).astype(np.uint8)
    return cv2.applyColorMap(x[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]


def _error_image(pred: np.ndarray, gt: np.ndarray, max_err: float = 5.0) -> np.ndarray:
    """RGB heat map of |pred - gt| where ground truth exists (dilated so sparse points show), black elsewhere."""
    valid = gt > 0
    err = np.where(valid, np.abs(pred - gt), 0.0)
    img = cv2.applyColorMap(np.clip(err / max_err * 255, 0, 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]
    if valid.mean() < 0.2:
        grow = cv2.dilate(valid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        img = cv2.dilate(np.where(valid[..., None], img, 0).astype(np.uint8), np.ones((3, 3), np.uint8))
        valid = grow
    return np.where(valid[..., None], img, 0).astype(np.uint8)


def _depth_image(d: np.ndarray) -> "rr.DepthImage":
    """Float metres (no 16-bit cap; hovering shows metres), 0 = unknown."""
    return rr.DepthImage(np.nan_to_num(d, nan=0.0).astype(np.float32), meter=1.0, colormap="turbo")


def write_recording(target: str | Path, out: str | Path, max_frames: int | None = None) -> dict:
    """`target` is a refine run folder (with metrics.json) or a sequence folder. Returns a summary."""
    target, out = Path(target), Path(out)
    run = target if (target / "metrics.json").is_file() and (target / "poses_kitti.txt").is_file() else None
    if run is not None:
        seq = open_sequence(_json_field(run / "metrics.json", "sequence"))
        poses = read_kitti_poses(run / "poses_kitti.txt")
        progress = read_json_object(run / "progress.json") if (run / "progress.json").is_file() else {}
        indices = sorted(int(k) for k in progress.get("poses", {})) or list(range(len(poses)))
    else:
        seq, poses, progress = open_sequence(target), None, {}
        indices = list(range(len(seq)))
    if max_frames is not None:
        indices = indices[:max_frames]
    if not indices:
        raise DataError(target, "nothing to record")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".part")
    try:
        strips = _record(tmp, run, seq, poses, progress, indices)
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)  # a failed recording leaves nothing behind
    return {"frames": len(indices), "trajectories": sorted(strips), "path": str(out)}


def _json_field(path: Path, key: str):
    doc = read_json_object(path)
    if key not in doc:
        raise DataError(path, f"has no '{key}' field")
    return doc[key]


def _record(tmp: Path, run: Path | None, seq, poses: np.ndarray | None, progress: dict, indices: list[int]) -> dict:
    """Log everything into the recording file `tmp`; returns the trajectory strips logged."""
    rec = rr.RecordingStream("leovr")
    rec.save(tmp, default_blueprint=blueprint())
    try:
        strips = _log_all(rec, run, seq, poses, progress, indices)
        rec.flush()
    finally:
        rec.disconnect()
    return strips


def _log_all(rec: "rr.RecordingStream", run: Path | None, seq, poses: np.ndarray | None, progress: dict,
             indices: list[int]) -> dict:
    rec.log("world", rr.ViewCoordinates.RDF, static=True)  # the first camera's axes: x right, y down, z forward
    strips = {}
    if poses is not None:
        strips["leovr"] = poses[: len(indices), :3, 3]
    icp = progress.get("icp_poses", {})
    if icp and all(str(i) in icp for i in indices):
        strips["kiss_icp"] = np.stack([np.array(icp[str(i)]).reshape(4, 4)[:3, 3] for i in indices])
    if run is not None and poses is not None and (run / "loops.json").is_file():
        at = {i: n for n, i in enumerate(indices)}
        pairs = [(at[r["frame"]], at[r["candidate"]]) for r in _json_field(run / "loops.json", "loops")
                 if r["accepted"] and r["frame"] in at and r["candidate"] in at]
        if pairs:
            rec.log("world/loops", rr.LineStrips3D([poses[[a, b], :3, 3] for a, b in pairs], colors=[(220, 40, 200)], radii=0.1),
                    static=True)
    if run is not None and (run / "landmarks.npy").is_file():
        rec.log("world/landmarks", rr.Points3D(np.load(run / "landmarks.npy"), colors=[(230, 230, 230)], radii=0.05), static=True)
    folders = {"generator": "depth_generator", "refined": "depth"}
    gt: list[np.ndarray] = []  # ground-truth positions relative to the first camera, while every frame has one
    T0_inv = None
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
        rec.log("world/camera/image", rr.Pinhole(image_from_camera=f.K, resolution=[f.width, f.height],
                                                 camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=2.0))
        rec.log("world/camera/image/rgb", rr.Image(f.image))
        if f.points is not None and len(f.points):
            cam = transform_points(f.T_cam_lidar, f.points[:, :3])
            rec.log("world/lidar", rr.Points3D(transform_points(T, cam), colors=_range_colours(np.linalg.norm(f.points[:, :3], axis=1)), radii=0.04))
        ref = f.depth
        for kind, folder in folders.items():
            if run is not None and run_frame_png(run, folder, i).is_file():
                d = read_run_depth(run, folder, i, f.shape)
                rec.log(f"world/camera/image/depth_{kind}", _depth_image(d))
                if kind == "refined" and ref is not None:
                    rec.log("world/camera/error", rr.Image(_error_image(d, ref)))
        if run is None and ref is not None:
            rec.log("world/camera/image/depth_ground_truth", _depth_image(ref))
    if T0_inv is not None:
        strips["ground_truth"] = np.stack([T[:3, 3] for T in gt])
    for name, xyz in strips.items():
        rec.log(f"world/trajectory/{name}", rr.LineStrips3D([xyz], colors=[COLOURS[name]], radii=0.08), static=True)
    return strips
