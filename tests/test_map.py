"""`leovr map`: a refine run fused into a TSDF mesh, scored against the rendered drive's dense ground truth, and
the pieces it is built from (the depth it keeps, the scores)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from leovr.config import MapConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.depth.classical import nearest_fill
from leovr.eval.map_metrics import distances_to_mesh, distances_to_points, map_scores
from leovr.geometry import back_project, transform_points
from leovr.lidar.projection import sparse_depth
from leovr.paths import REPO_ROOT
from leovr.pipeline.tsdf_map import TsdfMap, map_depth
from leovr.sim.simulate import simulate


def _truth_points(seq, run_poses: np.ndarray, max_depth: float) -> np.ndarray:
    """Every 8th pixel of each frame's dense ground-truth depth, in the run's world (its first camera)."""
    T0_inv = np.linalg.inv(seq[0].T_world_cam)
    out = []
    for i in range(len(seq)):
        f = seq[i]
        v, u = np.mgrid[0 : f.height : 8, 0 : f.width : 8]
        z = f.depth[v, u]
        keep = (z > 0) & (z <= max_depth)
        cam = back_project(np.stack([u[keep], v[keep]], 1).astype(float), z[keep].astype(float), f.K)
        out.append(transform_points(run_poses[0] @ T0_inv @ f.T_world_cam, cam))
    return np.concatenate(out)


@pytest.mark.slow
def test_a_refined_run_maps_the_rendered_drive_better_than_the_nearest_fill(tmp_path):
    """`leovr refine --map` on 6 frames of a rendered Mid-40 drive: a coloured mesh close to the true surfaces, more
    accurate
    and more complete than the map fused from the nearest fill of the same scans with the same poses."""
    import open3d as o3d

    simulate(SimulateConfig(scenario="city_loop", lidar="mid40", frames=6, seed=3), tmp_path / "sim", progress=False)
    run = tmp_path / "run"
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "from leovr.cli import main; main()",
            "refine",
            str(tmp_path / "sim"),
            "--out",
            str(run),
            "--map",
        ],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "map: 6 frames" in r.stdout and "WARNING" not in r.stdout  # nothing of Open3D's on stdout
    summary = json.loads((run / "map" / "map.json").read_text())
    assert summary["uncertainty_filter"] == (MapConfig().sigma_max is not None) and summary["triangles"] > 10000
    mesh = o3d.io.read_triangle_mesh(str(run / "map" / "map.ply"))
    assert mesh.has_vertex_colors() and len(mesh.triangles) == summary["triangles"]
    assert len(o3d.io.read_point_cloud(str(run / "map" / "map_points.ply")).points) == summary["vertices"]
    seq, poses = open_sequence(tmp_path / "sim"), read_kitti_poses(run / "poses_kitti.txt")
    truth = _truth_points(seq, poses, MapConfig().max_depth_m)
    refined = map_scores(distances_to_mesh(mesh, truth))
    nearest = TsdfMap(MapConfig())
    for i in range(len(seq)):
        f = seq[i]
        fill = nearest_fill(sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape))
        nearest.add(f.image, map_depth(fill, None, MapConfig(), f.K[0, 0]), f.K, poses[i])
    near = map_scores(distances_to_mesh(nearest.mesh(), truth))
    assert refined["accuracy_m"] < 0.3 and refined["completeness"] > 0.45, refined
    assert refined["accuracy_m"] < 0.8 * near["accuracy_m"] and refined["completeness"] > 1.3 * near["completeness"], (
        refined,
        near,
    )


def test_a_surface_needs_more_views_than_min_weight():
    """`min_weight` 1 (the default): a wall seen by one frame is not in the map, seen by two it is; 0 keeps it at
    one."""
    K = np.array([[200.0, 0, 100], [0, 200, 60], [0, 0, 1]])
    image, wall = np.zeros((120, 200, 3), np.uint8), np.full((120, 200), 5.0, np.float32)
    triangles = {}
    for min_weight, frames in ((1.0, 1), (1.0, 2), (0.0, 1)):
        vol = TsdfMap(MapConfig(min_weight=min_weight))
        for _ in range(frames):
            vol.add(image, wall, K, np.eye(4))
        triangles[min_weight, frames] = len(vol.mesh().triangles)
    assert triangles[1.0, 1] == 0 and triangles[1.0, 2] > 5000 and triangles[0.0, 1] == triangles[1.0, 2]


def test_the_map_keeps_depth_in_reach_certain_enough_and_off_depth_edges():
    depth = np.array([[5.0, 50.0, 10.0, 0.0]], np.float32)
    sigma = np.array([[0.5, 1.0, 5.0, 0.0]], np.float32)
    cfg = MapConfig(max_depth_m=40.0, sigma_max=0.3, edge_jump=None)
    assert map_depth(depth, sigma, cfg).tolist() == [[5.0, 0.0, 0.0, 0.0]]  # too far; 5 m of 10 m is too uncertain
    assert map_depth(depth, sigma, cfg.model_copy(update={"sigma_max": None})).tolist() == [[5.0, 0.0, 10.0, 0.0]]
    wall = np.full((4, 6), 10.0, np.float32)  # a car 10 m away in front of a wall at 20 m: the edge's columns go
    wall[:, 3:] = 20.0
    assert (map_depth(wall, None, MapConfig(edge_jump=0.05)) > 0).tolist() == [
        [True, True, False, False, True, True]
    ] * 4
    ramp = np.tile(10.0 * 1.02 ** np.arange(6, dtype=np.float32), (4, 1))  # a steep smooth surface: 2 % a pixel
    assert (map_depth(ramp, None, MapConfig(edge_jump=0.05)) > 0).all()


def test_map_scores_on_a_known_plane():
    """A 10 m square at z = 0: points 0.1 m above count as complete, 0.5 m above as covered but not complete,
    3 m above as not covered (left out of the accuracy)."""
    import open3d as o3d

    plane = o3d.geometry.TriangleMesh.create_box(10.0, 10.0, 0.001).translate((-5.0, -5.0, -0.001))
    pts = np.array([[0, 0, 0.1], [1, 1, 0.1], [2, 2, 0.5], [0, 1, 3.0]])
    s = map_scores(distances_to_mesh(plane, pts))
    assert s["n"] == 4 and s["completeness"] == 0.5 and s["covered"] == 0.75
    assert s["accuracy_m"] == pytest.approx((0.1 + 0.1 + 0.5) / 3, abs=1e-3)
    assert distances_to_points(np.zeros((1, 3)), np.array([[0, 3.0, 4.0]])).tolist() == [5.0]
    empty = map_scores(distances_to_mesh(o3d.geometry.TriangleMesh(), pts))
    assert empty["accuracy_m"] is None and empty["completeness"] == 0.0


def test_held_out_returns_are_placed_with_the_ground_truth_moved_onto_the_runs_trajectory():
    """On a clip with poses the held-out returns are placed with the ground-truth poses, then moved rigidly onto the
    run's trajectory: a run whose poses are the truth turned and shifted as a whole gets the same truth points,
    turned and shifted alike (the maps are scored on their shape, not on the frame the run's first pose set), also
    when the drive is straight (its centres alone leave the roll about it open)."""
    from types import SimpleNamespace

    from leovr.bench.map import heldout_world_points
    from leovr.geometry import make_T, transform_points
    from scipy.spatial.transform import Rotation

    K = np.array([[500.0, 0, 160], [0, 500, 120], [0, 0, 1]])
    truth = np.stack(
        [make_T(Rotation.from_euler("y", 2 * i, degrees=True).as_matrix(), [0.3 * i, 0, 1.1 * i]) for i in range(6)]
    )
    seq = type(
        "Seq",
        (),
        {
            "has_poses": True,
            "pose": staticmethod(lambda i: truth[i]),
            "__getitem__": lambda self, i: SimpleNamespace(K=K),
        },
    )()
    frames = {
        i: SimpleNamespace(gt=np.array([5.0, 12.0, 30.0]), pick=(np.array([10, 100, 200]), np.array([20, 160, 300])))
        for i in range(6)
    }
    moved = make_T(Rotation.from_euler("xyz", [3, -20, 5], degrees=True).as_matrix(), [4.0, -1.0, 2.5])
    placed_on_truth = heldout_world_points(seq, frames, truth, 25.0)
    placed_on_moved = heldout_world_points(seq, frames, np.einsum("ij,fjk->fik", moved, truth), 25.0)
    assert len(placed_on_truth) == 12  # the 30 m return is out of reach
    assert np.allclose(placed_on_moved, transform_points(moved, placed_on_truth), atol=1e-6)
