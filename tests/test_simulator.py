"""The procedural world and its sensors: analytic depth, LiDAR geometry, masks, determinism."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from leovr.config import SimulateConfig
from leovr.data import open_sequence
from leovr.lidar import deskew
from leovr.sim.meshes import Mat, MeshBuilder
from leovr.sim.render import LIGHTS, build_scene, render_camera
from leovr.sim.sensors import LIDARS, SWEEP_S, T_VEHICLE_CAM, CameraModel
from leovr.sim.simulate import simulate, vehicle_poses
from leovr.sim.world import build_world


@pytest.fixture(scope="module")
def hdl_seq(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "hdl"
    simulate(SimulateConfig(lidar="hdl64", frames=3, scenario="city_loop"), out, preview=True, progress=False)
    return out


def test_wall_depth_equals_analytic_value():
    b = MeshBuilder()
    b.box((30.0, 0.0, -60.0), (20.0, 200.0, 120.0), Mat.FACADE, (0.5, 0.5, 0.5), param=(3.0, 1))  # front face at x = 20
    scene = build_scene(b.build(), MeshBuilder().build())
    cam = CameraModel()
    img, depth, moving = render_camera(
        scene,
        T_VEHICLE_CAM,
        cam.ray_directions(),
        (cam.height, cam.width),
        cam.fx,
        LIGHTS["day"],
        np.random.default_rng(0),
    )
    # the camera sits 1.0 m ahead of the vehicle origin, looking along +x: z-depth of the wall is 19 m everywhere
    np.testing.assert_allclose(depth, 19.0, atol=2e-3)
    assert img.shape == (256, 448, 3) and not moving.any() and img.std() > 5  # textured, not flat


def test_lidar_returns_lie_on_surfaces_and_deskew_matters(hdl_seq):
    seq = open_sequence(hdl_seq)
    cfg = SimulateConfig.model_validate(seq.meta["simulation"])
    world = build_world(cfg.scenario, cfg.seed, cfg.speed_kmh / 3.6)
    f = seq[2]
    dyn = world.dynamic_mesh(f.timestamp)
    rc = o3d.t.geometry.RaycastingScene()
    for m in (world.static, dyn):
        rc.add_triangles(o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.triangles.astype(np.uint32)))
    lidar = LIDARS["hdl64"]
    T_ws = vehicle_poses(world, f.timestamp + f.point_times, cfg.speed_kmh / 3.6) @ lidar.T_vehicle_lidar
    world_pts = np.einsum("nij,nj->ni", T_ws[:, :3, :3], f.points[:, :3].astype(np.float64)) + T_ws[:, :3, 3]
    dist = rc.compute_distance(o3d.core.Tensor(world_pts.astype(np.float32))).numpy()
    assert np.median(dist) < 0.03 and np.quantile(dist, 0.99) < 0.1  # 2 cm range noise
    assert f.point_times.min() >= 0 and f.point_times.max() < SWEEP_S

    # deskewed to the camera time, static returns agree with the dense ground-truth depth
    T0 = vehicle_poses(world, np.array([f.timestamp]), cfg.speed_kmh / 3.6)[0] @ lidar.T_vehicle_lidar
    T1 = vehicle_poses(world, np.array([f.timestamp + SWEEP_S]), cfg.speed_kmh / 3.6)[0] @ lidar.T_vehicle_lidar

    def off_surface(points):
        """Distance to the nearest surface of points read as if all were measured at the sweep start."""
        w = points[:, :3].astype(np.float64) @ T0[:3, :3].T + T0[:3, 3]
        return rc.compute_distance(o3d.core.Tensor(w.astype(np.float32))).numpy()

    fixed = deskew(f.points, f.point_times, T0, T1, SWEEP_S, t_ref=0.0)
    d_fixed, d_raw = off_surface(fixed), off_surface(f.points)
    assert np.median(d_fixed) < 0.03 and np.quantile(d_fixed, 0.99) < 0.15
    assert np.quantile(d_raw, 0.9) > 5 * np.quantile(d_fixed, 0.9)


def test_vlp16_has_16_rings_and_hdl64_64(tmp_path):
    simulate(SimulateConfig(lidar="vlp16", frames=1), tmp_path / "v", progress=False)
    pts = open_sequence(tmp_path / "v")[0].points
    el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    np.testing.assert_allclose(np.unique(np.round(el, 2)), np.linspace(-15, 15, 16), atol=0.01)


def test_hdl64_rings(hdl_seq):
    pts = open_sequence(hdl_seq)[0].points
    el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    assert len(np.unique(np.round(el, 2))) == 64 and el.max() < 2.01 and el.min() > -24.81


def test_mid40_cone_and_coverage_grows_over_time(tmp_path):
    simulate(SimulateConfig(lidar="mid40", frames=5, scenario="straight"), tmp_path / "m", progress=False)
    seq = open_sequence(tmp_path / "m")
    cells = []
    for f in seq:
        d = f.points[:, :3] / np.linalg.norm(f.points[:, :3], axis=1, keepdims=True)
        off_axis = np.degrees(np.arccos(np.clip(d[:, 0], -1, 1)))
        assert off_axis.max() <= 19.2 + 1e-3 and 4_000 < len(f.points) <= 10_000
        az, el = np.degrees(np.arctan2(d[:, 1], d[:, 0])), np.degrees(np.arcsin(d[:, 2]))
        cells.append(set(zip(np.floor(az / 0.4).astype(int), np.floor(el / 0.4).astype(int))))
    union = [len(set().union(*cells[: k + 1])) for k in range(len(cells))]
    assert all(b > a for a, b in zip(union, union[1:])) and union[-1] > 1.8 * union[0]


def test_moving_mask_moves_and_marks_movers(tmp_path):
    simulate(SimulateConfig(scenario="dynamic", frames=6, lidar="mid40"), tmp_path / "d", progress=False)
    seq = open_sequence(tmp_path / "d")
    a, b = seq[0].moving_mask, seq[5].moving_mask
    assert a.any() and b.any()
    assert (a ^ b).sum() > 0.2 * max(a.sum(), b.sum())
    # consecutive camera positions are one frame of travel apart (30 km/h at 10 Hz)
    p = np.stack([f.T_world_cam[:3, 3] for f in seq])
    np.testing.assert_allclose(np.linalg.norm(np.diff(p, axis=0), axis=1), 30 / 3.6 / 10, rtol=0.02)


@pytest.mark.slow
def test_same_seed_gives_identical_files_and_other_seed_differs(tmp_path):
    cfg = SimulateConfig(frames=2, lidar="vlp16", scenario="dynamic")
    for name in ("a", "b"):
        simulate(cfg, tmp_path / name, progress=False)
    simulate(cfg.model_copy(update={"seed": 1}), tmp_path / "c", progress=False)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) >= 10
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    assert (tmp_path / "a" / "images" / "000000.png").read_bytes() != (
        tmp_path / "c" / "images" / "000000.png"
    ).read_bytes()


def test_ground_truth_reaches_long_range_and_preview_exists(hdl_seq):
    seq = open_sequence(hdl_seq)
    assert seq.depth_scale == 256.0
    d = seq[0].depth
    assert (d > 0).mean() > 0.8 and d.max() > 100.0  # structure well beyond 65.5 m
    import cv2

    prev = cv2.imread(str(hdl_seq / "preview.png"))
    assert prev.shape == (3 * 256, 448, 3)


def test_night_is_darker_and_noisier(tmp_path):
    for light in ("day", "night"):
        simulate(SimulateConfig(frames=1, light=light), tmp_path / light, progress=False)
    day, night = open_sequence(tmp_path / "day")[0].image, open_sequence(tmp_path / "night")[0].image
    assert night.mean() < 0.5 * day.mean()
    np.testing.assert_array_equal(open_sequence(tmp_path / "day")[0].depth, open_sequence(tmp_path / "night")[0].depth)


def test_dataset_splits_use_disjoint_seeds_and_resume(tmp_path):
    from leovr.sim.dataset import Recipe, make_dataset

    recipe = Recipe("t", {"train": 2, "test": 1}, ("mid40",), ("day",), 2)
    seeds = {split: {cfg.seed for s, cfg in recipe.items() if s == split} for split in ("train", "test")}
    assert not seeds["train"] & seeds["test"]
    root = make_dataset(recipe, tmp_path, progress=False)
    import json

    manifest = json.loads((root / "manifest.json").read_text())
    assert len(manifest["sequences"]) == 3
    first = root / manifest["sequences"][0]["path"] / "images" / "000000.png"
    stamp = first.stat().st_mtime_ns
    make_dataset(recipe, tmp_path, progress=False)  # complete sequences are not rendered again
    assert first.stat().st_mtime_ns == stamp
    assert len(open_sequence(root / manifest["sequences"][2]["path"])) == 2
