"""Triangle-soup builder with per-triangle material, colour and parameters (numpy only)."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class Mat(IntEnum):
    GROUND = 0
    ROAD = 1
    SIDEWALK = 2
    FACADE = 3
    ROOF = 4
    METAL = 5
    SIGN = 6
    TRUNK = 7
    FOLIAGE = 8
    CAR = 9
    PERSON = 10


_BOX_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
_BOX_F = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ]
)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@dataclass
class Mesh:
    """Vertices (V x 3), triangles (T x 3) and per-triangle material, base colour and two parameters."""

    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    material: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    color: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    param: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


class MeshBuilder:
    """Accumulates primitives; `build()` concatenates them once."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._m: list[np.ndarray] = []
        self._c: list[np.ndarray] = []
        self._p: list[np.ndarray] = []
        self._n = 0

    def add(self, v: np.ndarray, f: np.ndarray, mat: Mat, color=(0.5, 0.5, 0.5), param=(0.0, 0.0)) -> None:
        self._v.append(np.asarray(v, float))
        self._f.append(np.asarray(f, np.int64) + self._n)
        k = len(f)
        self._m.append(np.full(k, int(mat)))
        self._c.append(np.tile(np.asarray(color, float), (k, 1)))
        self._p.append(np.tile(np.asarray(param, float), (k, 1)))
        self._n += len(v)

    def add_mesh(self, mesh: Mesh, yaw: float = 0.0, offset=(0.0, 0.0, 0.0)) -> None:
        """Place a template mesh (rotated by `yaw` about z, then shifted), keeping its per-triangle attributes."""
        self._v.append(mesh.vertices @ _rot_z(yaw).T + np.asarray(offset, float))
        self._f.append(mesh.triangles + self._n)
        self._m.append(mesh.material)
        self._c.append(mesh.color)
        self._p.append(mesh.param)
        self._n += len(mesh.vertices)

    def box(self, center, size, mat: Mat, color=(0.5, 0.5, 0.5), yaw: float = 0.0, param=(0.0, 0.0)) -> None:
        """Axis-aligned box (rotated by `yaw` about z) with its base centred at `center`."""
        size = np.asarray(size, float)
        v = (_BOX_V - [0.5, 0.5, 0.0]) * size
        self.add(v @ _rot_z(yaw).T + np.asarray(center, float), _BOX_F, mat, color, param)

    def quad(self, x0, y0, x1, y1, z, mat: Mat, color=(0.5, 0.5, 0.5), param=(0.0, 0.0)) -> None:
        """Horizontal rectangle facing up."""
        v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
        self.add(v, np.array([[0, 1, 2], [0, 2, 3]]), mat, color, param)

    def prism(self, center, radius: float, height: float, mat: Mat, color=(0.5, 0.5, 0.5), sides: int = 8) -> None:
        """Vertical n-sided prism (poles, trunks) with its base centred at `center`."""
        a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
        ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(sides)], 1)
        v = np.vstack([ring, ring + [0, 0, height]]) + np.asarray(center, float)
        i = np.arange(sides)
        j = (i + 1) % sides
        f = np.vstack([np.stack([i, j, j + sides], 1), np.stack([i, j + sides, i + sides], 1)])
        self.add(v, f, mat, color)

    def blob(self, center, radius: float, mat: Mat, color=(0.5, 0.5, 0.5)) -> None:
        """Low-poly ball (an icosahedron), e.g. a tree crown."""
        t = (1 + 5**0.5) / 2
        v = np.array(
            [
                [-1, t, 0],
                [1, t, 0],
                [-1, -t, 0],
                [1, -t, 0],
                [0, -1, t],
                [0, 1, t],
                [0, -1, -t],
                [0, 1, -t],
                [t, 0, -1],
                [t, 0, 1],
                [-t, 0, -1],
                [-t, 0, 1],
            ],
            float,
        )
        v = v / np.linalg.norm(v[0]) * radius + np.asarray(center, float)
        f = np.array(
            [
                [0, 11, 5],
                [0, 5, 1],
                [0, 1, 7],
                [0, 7, 10],
                [0, 10, 11],
                [1, 5, 9],
                [5, 11, 4],
                [11, 10, 2],
                [10, 7, 6],
                [7, 1, 8],
                [3, 9, 4],
                [3, 4, 2],
                [3, 2, 6],
                [3, 6, 8],
                [3, 8, 9],
                [4, 9, 5],
                [2, 4, 11],
                [6, 2, 10],
                [8, 6, 7],
                [9, 8, 1],
            ]
        )
        self.add(v, f, mat, color)

    def build(self) -> Mesh:
        if not self._v:
            return Mesh()
        return Mesh(
            np.vstack(self._v), np.vstack(self._f), np.concatenate(self._m), np.vstack(self._c), np.vstack(self._p)
        )


def car_template(color) -> Mesh:
    """A car in its own frame (x forward, base at z = 0): body and cabin."""
    b = MeshBuilder()
    b.box((0, 0, 0.25), (4.3, 1.8, 0.75), Mat.CAR, color)
    b.box((-0.3, 0, 1.0), (2.3, 1.6, 0.55), Mat.CAR, color, param=(1.0, 0.0))  # param 1: glass band
    return b.build()


def person_template(color) -> Mesh:
    b = MeshBuilder()
    b.box((0, 0, 0.0), (0.3, 0.45, 0.9), Mat.PERSON, (0.15, 0.15, 0.25))
    b.box((0, 0, 0.9), (0.3, 0.5, 0.6), Mat.PERSON, color)
    b.box((0, 0, 1.5), (0.22, 0.22, 0.25), Mat.PERSON, (0.8, 0.6, 0.5))
    return b.build()
