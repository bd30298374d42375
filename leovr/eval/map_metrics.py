"""How well a 3D map explains returns no method saw: accuracy (mean distance of the held-out points to the map,
over the points the map covers) and completeness (the share of held-out points within `near_m` of it)."""

from __future__ import annotations

import numpy as np

NEAR_M = 0.2  # a held-out point within this of the map counts towards completeness
COVER_M = 1.0  # farther than this, the map does not cover the point: left out of the accuracy


def distances_to_mesh(mesh, points: np.ndarray) -> np.ndarray:
    """Distance of each point (N x 3, world) to an Open3D legacy TriangleMesh (inf when it is empty)."""
    import open3d as o3d

    if not len(mesh.triangles):
        return np.full(len(points), np.inf)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy().astype(np.float64)


def distances_to_points(cloud: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest point of `cloud` (M x 3; inf when it is empty)."""
    from scipy.spatial import cKDTree

    if not len(cloud):
        return np.full(len(points), np.inf)
    return cKDTree(np.asarray(cloud, np.float64)).query(np.asarray(points, np.float64), workers=-1)[0]


def map_scores(dist: np.ndarray, near_m: float = NEAR_M, cover_m: float = COVER_M) -> dict:
    """Accuracy (m, over the points within `cover_m`), completeness and coverage of held-out points at
    distances `dist` from a map."""
    dist = np.asarray(dist, np.float64)
    covered = dist <= cover_m
    return {
        "n": int(len(dist)),
        "accuracy_m": float(dist[covered].mean()) if covered.any() else None,
        "completeness": float((dist <= near_m).mean()) if len(dist) else None,
        "covered": float(covered.mean()) if len(dist) else None,
    }
