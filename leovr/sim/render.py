"""Ray-cast rendering of the world: camera image, z-depth and moving mask; LiDAR returns with time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from leovr.sim.meshes import Mat, Mesh
from leovr.sim.noise import fractal_noise
from leovr.sim.world import KERB, ROAD_HALF

NO_HIT = np.uint32(0xFFFFFFFF)


@dataclass(frozen=True)
class Light:
    sun_dir: tuple[float, float, float] | None
    sun_rgb: tuple[float, float, float]
    ambient_rgb: tuple[float, float, float]
    sky_top: tuple[float, float, float]
    sky_horizon: tuple[float, float, float]
    headlights: float
    gain: float
    read_noise: float


LIGHTS = {
    "day": Light(
        (0.45, 0.3, 0.84), (0.8, 0.78, 0.72), (0.42, 0.44, 0.48), (0.3, 0.5, 0.85), (0.75, 0.82, 0.92), 0.0, 1.0, 0.004
    ),
    "dusk": Light(
        (-0.7, 0.55, 0.18),
        (0.95, 0.6, 0.35),
        (0.25, 0.23, 0.28),
        (0.2, 0.22, 0.42),
        (0.95, 0.55, 0.35),
        0.3,
        0.8,
        0.012,
    ),
    "night": Light(None, (0, 0, 0), (0.035, 0.04, 0.06), (0.005, 0.006, 0.015), (0.03, 0.03, 0.05), 2.5, 1.0, 0.03),
}


@dataclass
class Scene:
    """An Open3D ray-casting scene of the static world (geometry 0) and the movers (geometry 1)."""

    rc: o3d.t.geometry.RaycastingScene
    meshes: tuple[Mesh, Mesh]


def build_scene(static: Mesh, dynamic: Mesh) -> Scene:
    rc = o3d.t.geometry.RaycastingScene()
    for m in (static, dynamic):
        if len(m.triangles):
            rc.add_triangles(
                o3d.core.Tensor(m.vertices.astype(np.float32)), o3d.core.Tensor(m.triangles.astype(np.uint32))
            )
        else:  # keep geometry ids stable: a degenerate far-away triangle
            v = np.array([[1e6, 1e6, -1e3], [1e6 + 1, 1e6, -1e3], [1e6, 1e6 + 1, -1e3]], np.float32)
            rc.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(np.array([[0, 1, 2]], np.uint32)))
    return Scene(rc, (static, dynamic))


@dataclass
class Hits:
    t: np.ndarray  # ray parameter (inf = miss)
    geom: np.ndarray  # 0 static, 1 dynamic, -1 miss
    tri: np.ndarray
    normal: np.ndarray


def cast(scene: Scene, origins: np.ndarray, dirs: np.ndarray) -> Hits:
    rays = np.hstack([origins, dirs]).astype(np.float32)
    r = scene.rc.cast_rays(o3d.core.Tensor(rays))
    g = r["geometry_ids"].numpy()
    return Hits(
        r["t_hit"].numpy().astype(np.float64),
        np.where(g == NO_HIT, -1, g.astype(np.int64)),
        r["primitive_ids"].numpy().astype(np.int64),
        r["primitive_normals"].numpy().astype(np.float64),
    )


def surface_attributes(scene: Scene, hits: Hits, hit_mask: np.ndarray):
    """Material, base colour and parameters of each hit triangle (hit rays only)."""
    n = int(hit_mask.sum())
    mat = np.zeros(n, np.int64)
    col = np.zeros((n, 3))
    par = np.zeros((n, 2))
    g, tri = hits.geom[hit_mask], hits.tri[hit_mask]
    for k, mesh in enumerate(scene.meshes):
        sel = g == k
        if sel.any() and len(mesh.triangles):
            mat[sel], col[sel], par[sel] = mesh.material[tri[sel]], mesh.color[tri[sel]], mesh.param[tri[sel]]
    return mat, col, par


def albedo(
    mat: np.ndarray, col: np.ndarray, par: np.ndarray, P: np.ndarray, nrm: np.ndarray, fp: np.ndarray
) -> np.ndarray:
    """Procedural surface colour at hit points P (world), with texture detail faded by pixel footprint fp."""
    out = col.copy()

    def tex(sel, freqs, amp, seed):
        if sel.any():
            out[sel] *= (1.0 + amp * fractal_noise(P[sel], freqs, fp[sel], seed))[:, None]

    tex(mat == Mat.GROUND, (0.7, 3.0, 12.0), 0.9, 1)
    road = mat == Mat.ROAD
    if road.any():
        tex(road, (1.5, 6.0, 24.0), 0.7, 2)
        axis, centre = par[road, 0], par[road, 1]
        Pr = P[road]
        lat = np.where(axis == 0, Pr[:, 1], Pr[:, 0]) - centre
        lon = np.where(axis == 0, Pr[:, 0], Pr[:, 1])
        dash = (np.abs(lat) < 0.1) & (np.mod(lon, 9.0) < 4.5)
        edge = np.abs(np.abs(lat) - (ROAD_HALF - 0.4)) < 0.08
        o = out[road]
        o[dash | edge] = (0.85, 0.85, 0.82)
        out[road] = o
    side = mat == Mat.SIDEWALK
    if side.any():
        tex(side, (2.0, 8.0), 0.4, 3)
        f = np.mod(P[side, :2], 1.0)
        out[side] *= np.where(((f < 0.04) | (f > 0.96)).any(axis=1), 0.6, 1.0)[:, None]
    fac = mat == Mat.FACADE
    if fac.any():
        tex(fac, (2.0, 8.0, 30.0), 0.45, 4)
        Pf, nf = P[fac], nrm[fac]
        h = np.where(np.abs(nf[:, 0]) > np.abs(nf[:, 1]), Pf[:, 1], Pf[:, 0])
        floor_h = par[fac, 0]
        u = np.mod(h, 2.6)
        v = np.mod(Pf[:, 2] - KERB, floor_h)
        window = (u > 0.6) & (u < 2.0) & (v > 0.9) & (v < floor_h - 0.5) & (Pf[:, 2] > 2.5) & (np.abs(nf[:, 2]) < 0.5)
        o = out[fac]
        tint = 0.15 + 0.1 * fractal_noise(Pf[window], (0.5, 3.0), fp[fac][window], 5)
        o[window] = np.stack([tint, tint + 0.03, tint + 0.1], 1)
        out[fac] = o
    tex(mat == Mat.ROOF, (1.0, 6.0), 0.4, 6)
    tex(mat == Mat.TRUNK, (4.0, 16.0), 0.5, 7)
    tex(mat == Mat.FOLIAGE, (2.0, 8.0, 24.0), 1.0, 8)
    tex((mat == Mat.METAL) | (mat == Mat.SIGN) | (mat == Mat.PERSON), (6.0,), 0.2, 9)
    glass = (mat == Mat.CAR) & (par[:, 0] == 1)
    out[glass] = (0.07, 0.09, 0.12)
    tex(mat == Mat.CAR, (5.0,), 0.15, 10)
    return np.clip(out, 0.0, 1.0)


def render_camera(
    scene: Scene,
    T_world_cam: np.ndarray,
    cam_dirs: np.ndarray,
    shape: tuple[int, int],
    fx: float,
    light: Light,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB uint8 image, z-depth (metres, 0 = sky) and moving-object mask of one camera view."""
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = cam_dirs @ R.T  # z-component 1 in the camera frame: t = depth
    hits = cast(scene, np.broadcast_to(o, d.shape), d)
    hit = np.isfinite(hits.t)
    depth = np.where(hit, hits.t, 0.0)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    # sky gradient by elevation
    elev = np.clip(unit[:, 2] * 3.0, 0.0, 1.0)[:, None]
    rgb = (1 - elev) * np.asarray(light.sky_horizon) + elev * np.asarray(light.sky_top)
    if hit.any():
        P = o + d[hit] * hits.t[hit, None]
        nrm = hits.normal[hit]
        ud = unit[hit]
        nrm = np.where((np.sum(nrm * ud, 1) > 0)[:, None], -nrm, nrm)
        cos_in = np.abs(np.sum(nrm * ud, 1))
        fp = depth[hit] / fx / np.maximum(cos_in, 0.25)
        mat, col, par = surface_attributes(scene, hits, hit)
        alb = albedo(mat, col, par, P, nrm, fp)
        irr = np.tile(np.asarray(light.ambient_rgb), (len(P), 1))
        if light.sun_dir is not None:
            sun = np.asarray(light.sun_dir) / np.linalg.norm(light.sun_dir)
            lam = np.clip(nrm @ sun, 0.0, None)
            lit = lam > 0
            shadow = cast(scene, P[lit] + nrm[lit] * 0.03, np.broadcast_to(sun, (int(lit.sum()), 3)))
            lam[np.nonzero(lit)[0][np.isfinite(shadow.t)]] = 0.0
            irr += lam[:, None] * np.asarray(light.sun_rgb)
        if light.headlights > 0:
            dist = depth[hit]
            fwd = np.clip((ud @ R[:, 2] - 0.8) / 0.2, 0.0, 1.0)
            irr += (light.headlights * cos_in * fwd / (1.0 + (dist / 10.0) ** 2))[:, None]
        rgb[hit] = alb * irr
    rgb = rgb * light.gain
    rgb = (
        rgb
        + rng.normal(0.0, light.read_noise, rgb.shape)
        + rng.normal(0.0, 1.0, rgb.shape) * np.sqrt(np.clip(rgb, 0, None)) * 0.01
    )
    img = (np.clip(rgb, 0.0, 1.0) ** (1 / 2.2) * 255.0 + 0.5).astype(np.uint8)
    h, w = shape
    moving = (hits.geom == 1).reshape(h, w)
    return img.reshape(h, w, 3), depth.reshape(h, w).astype(np.float32), moving


def scan_lidar(
    scene: Scene,
    T_world_sensor: np.ndarray,
    beams: np.ndarray,
    max_range: float,
    noise: float,
    dropout: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Cast each beam from the sensor pose at its firing time (M x 4 x 4); return kept points in the
    sensor frame at that time (x, y, z, intensity) and the mask of kept beams."""
    d = np.einsum("nij,nj->ni", T_world_sensor[:, :3, :3], beams)
    o = T_world_sensor[:, :3, 3]
    hits = cast(scene, o, d)
    rng_noise = rng.normal(0.0, noise, len(beams))
    keep = np.isfinite(hits.t) & (hits.t <= max_range) & (rng.random(len(beams)) >= dropout)
    r = hits.t[keep] + rng_noise[keep]
    pts = beams[keep] * r[:, None]
    _, col, _ = surface_attributes(scene, hits, keep)
    nrm = hits.normal[keep]
    cos_in = np.abs(np.sum(nrm * d[keep], 1))
    intensity = np.clip(col.mean(axis=1) * (0.3 + 0.7 * cos_in), 0.0, 1.0)
    return np.hstack([pts, intensity[:, None]]).astype(np.float32), keep
