"""Sensor models and mounting: pinhole camera, spinning LiDARs (VLP-16, HDL-64), Livox Mid-40."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leovr.geometry import invert_T, make_T
from leovr.lidar.cheap_sensor import rosette_directions

SWEEP_S = 0.1
# vehicle frame: x forward, y left, z up; camera frame: x right, y down, z forward
R_VEHICLE_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_VEHICLE_CAM = make_T(R_VEHICLE_CAM, [1.0, 0.0, 1.65])


@dataclass(frozen=True)
class CameraModel:
    width: int = 448
    height: int = 256
    fx: float = 260.0
    fy: float = 260.0

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def ray_directions(self) -> np.ndarray:
        """H*W x 3 camera-frame directions with z = 1 (so ray length parameter = depth), row-major."""
        v, u = np.mgrid[0 : self.height, 0 : self.width]
        return np.stack([(u.ravel() - self.cx) / self.fx, (v.ravel() - self.cy) / self.fy, np.ones(u.size)], 1)


@dataclass(frozen=True)
class LidarModel:
    name: str
    mount: tuple[float, float, float]  # position in the vehicle frame; axes = vehicle axes
    max_range: float
    range_noise: float = 0.02
    dropout: float = 0.01

    @property
    def T_vehicle_lidar(self) -> np.ndarray:
        return make_T(None, self.mount)

    @property
    def T_cam_lidar(self) -> np.ndarray:
        return invert_T(T_VEHICLE_CAM) @ self.T_vehicle_lidar

    def beams(self, frame_index: int) -> tuple[np.ndarray, np.ndarray]:
        """Unit beam directions (sensor frame) and firing times within the sweep, in storage order.

        Spinning sensors store ring after ring (top ring first), azimuth rising from -pi, like KITTI.
        """
        if self.name == "mid40":
            d = rosette_directions(frame_index * SWEEP_S, SWEEP_S)
            return d, np.arange(len(d)) / 100_000.0
        if self.name == "vlp16":
            el, cols = np.linspace(15.0, -15.0, 16), 1800
        elif self.name == "hdl64":
            el, cols = np.linspace(2.0, -24.8, 64), 2000
        else:
            raise ValueError(f"unknown LiDAR '{self.name}' (choose vlp16, hdl64, mid40)")
        az = -np.pi + np.arange(cols) * (2 * np.pi / cols)
        E, A = np.meshgrid(np.radians(el), az, indexing="ij")
        d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
        t = np.tile((az + np.pi) / (2 * np.pi) * SWEEP_S, len(el))
        return d, t


# spinning sensors sit 0.27 m behind and 0.08 m above the camera (as on KITTI's car); the Mid-40 just
# below the camera, looking forward
LIDARS = {
    "vlp16": LidarModel("vlp16", (0.73, 0.0, 1.73), 100.0),
    "hdl64": LidarModel("hdl64", (0.73, 0.0, 1.73), 120.0),
    "mid40": LidarModel("mid40", (1.05, 0.0, 1.50), 260.0),
}
