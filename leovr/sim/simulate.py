"""`leovr simulate`: render a native-format sequence from a procedural world.

Frame k is exposed at t_k = k / rate; the LiDAR sweeps [t_k, t_k + 0.1 s) from the moving vehicle
(each beam from the pose at its firing time, so deskew matters); movers are frozen at t_k within a
frame. Ground-truth depth is written at 256 units per metre (`depth_scale: 256` in sequence.yaml,
KITTI's depth convention) because millimetres in 16 bits stop at 65.5 m and the world reaches 150 m+.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from leovr.config import SimulateConfig
from leovr.data.io import write_image
from leovr.data.native import NativeWriter
from leovr.data.records import Frame
from leovr.errors import DataError
from leovr.lidar.projection import project_points
from leovr.sim.render import LIGHTS, build_scene, render_camera, scan_lidar
from leovr.sim.sensors import LIDARS, T_VEHICLE_CAM, CameraModel
from leovr.sim.world import World, build_world

GT_DEPTH_SCALE = 256.0


def vehicle_poses(world: World, times: np.ndarray, speed: float) -> np.ndarray:
    """Vehicle-to-world poses (N x 4 x 4) along the ego path, with a little pitch and roll from the
    suspension so the motion is not exactly planar."""
    t = np.asarray(times, np.float64)
    xy, yaw = world.ego_path.pose(speed * t)
    pitch = np.radians(0.3) * np.sin(2 * np.pi * 0.7 * t + world.seed)
    roll = np.radians(0.2) * np.sin(2 * np.pi * 0.45 * t + 2 * world.seed)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], 1)).as_matrix()
    T[:, :2, 3] = xy
    return T


def render_frame(world: World, cfg: SimulateConfig, k: int, cam: CameraModel, cam_dirs: np.ndarray) -> Frame:
    """Render camera, depth, moving mask and LiDAR sweep of frame k."""
    speed = cfg.speed_kmh / 3.6
    lidar = LIDARS[cfg.lidar]
    t = k / cfg.rate_hz
    dynamic = world.dynamic_mesh(t)
    scene = build_scene(world.static, dynamic)
    rng = np.random.default_rng([cfg.seed, k, 7])
    T_wc = vehicle_poses(world, np.array([t]), speed)[0] @ T_VEHICLE_CAM
    img, depth, moving = render_camera(scene, T_wc, cam_dirs, (cam.height, cam.width), cam.fx, LIGHTS[cfg.light], rng)
    beams, bt = lidar.beams(k)
    T_ws = vehicle_poses(world, t + bt, speed) @ lidar.T_vehicle_lidar
    pts, keep = scan_lidar(scene, T_ws, beams, lidar.max_range, lidar.range_noise, lidar.dropout, rng)
    return Frame(k, t, img, cam.K, lidar.T_cam_lidar, pts, bt[keep], T_wc, depth, moving)


def preview_image(frame: Frame) -> np.ndarray:
    """Image, colour-coded depth and LiDAR overlay (moving objects outlined), stacked vertically."""
    h, w = frame.shape
    d = frame.depth
    inv = np.where(d > 0, 1.0 / np.maximum(d, 1e-3), 0.0)
    inv_u8 = (np.clip(inv / 0.5, 0, 1) ** 0.5 * 255).astype(np.uint8)
    depth_rgb = cv2.cvtColor(cv2.applyColorMap(inv_u8, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    depth_rgb[d <= 0] = 0
    overlay = (frame.image * 0.5).astype(np.uint8)
    proj = project_points(frame.points, frame.K, frame.T_cam_lidar, (h, w))
    z = np.clip(1.0 / proj.depth / 0.5, 0, 1) ** 0.5
    colors = cv2.applyColorMap((z * 255).astype(np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    for du in (0, 1):
        uu = np.clip(proj.u + du, 0, w - 1)
        overlay[proj.v, uu] = colors
    if frame.moving_mask is not None and frame.moving_mask.any():
        edge = cv2.morphologyEx(frame.moving_mask.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        overlay[edge] = (255, 0, 255)
    return np.vstack([frame.image if frame.image.ndim == 3 else np.dstack([frame.image] * 3), depth_rgb, overlay])


def check_replaceable(out: Path) -> None:
    """A folder holding a sequence is rendered over only when that sequence is an earlier rendering: a
    recording (or a conversion of one) is never replaced."""
    from leovr.data.io import read_yaml

    meta_file = out / "sequence.yaml"
    if meta_file.is_file():
        meta = read_yaml(meta_file)
        if not isinstance(meta, dict) or "simulation" not in meta:
            raise DataError(out, "holds a recorded sequence, not an earlier rendering; render into another folder")


def simulate(cfg: SimulateConfig, out: Path, preview: bool = False, progress: bool = True) -> dict:
    """Render `cfg.frames` frames into `out` (native format); returns timing figures."""
    check_replaceable(Path(out))
    world = build_world(cfg.scenario, cfg.seed, cfg.speed_kmh / 3.6)
    cam = CameraModel(cfg.width, cfg.height, cfg.focal, cfg.focal)
    cam_dirs = cam.ray_directions()
    writer = NativeWriter(
        out,
        name=f"{cfg.scenario}_{cfg.lidar}_{cfg.light}_s{cfg.seed}",
        rate_hz=cfg.rate_hz,
        lidar_name=cfg.lidar,
        extra={"simulation": cfg.model_dump()},
        depth_scale=GT_DEPTH_SCALE,
        camera_height_m=float(T_VEHICLE_CAM[2, 3]),  # the vehicle's frame lies on the road
        overwrite=True,  # rendered again from its settings: an earlier rendering in `out` is replaced
    )
    times = []
    middle = None
    for k in tqdm(range(cfg.frames), desc=f"simulate {cfg.scenario}/{cfg.lidar}", unit="frame", disable=not progress):
        t0 = time.perf_counter()
        frame = render_frame(world, cfg, k, cam, cam_dirs)
        times.append(time.perf_counter() - t0)
        writer.write(frame)
        if preview and k == cfg.frames // 2:
            middle = frame
    writer.close()
    if middle is not None:
        write_image(Path(out) / "preview.png", preview_image(middle))
    return {"frames": cfg.frames, "s_per_frame": float(np.mean(times)), "frames_per_s": float(1.0 / np.mean(times))}
