"""`leovr map`: a run's refined depth, colour images and poses fused into one 3D map of the drive.

Each frame's depth is integrated into a truncated signed distance volume: Open3D's voxel-block grid (a hash
map of 8^3-voxel blocks, allocated only near observed surfaces, so memory grows with the area driven, not
with the frame count). Pixels beyond `max_depth_m`, on depth edges (`edge_jump`), and, when asked, pixels whose
predicted uncertainty (the generator's sigma over the depth, `sigma/`) is above `sigma_max`, are left out. The zero
level set is written as a
coloured triangle mesh (`map.ply`) and its vertices as a coloured point cloud (`map_points.ply`).
"""

from __future__ import annotations

import json
import resource
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from leovr.config import MapConfig
from leovr.data.io import atomic_write, read_depth_png, write_text
from leovr.data.run_folder import RunFolder, read_run
from leovr.errors import DataError

SIGMA_SCALE = 256.0  # sigma/ PNGs: uint16 = metres x 256, as the depth maps


# Open3D 0.20 crashes (SIGSEGV) extracting the surface of a voxel-block grid of about 285k blocks (a 200-frame
# rendered drive at 5 cm): a volume that grows past this many blocks has its surface taken out and starts afresh
MAX_BLOCKS = 150_000


TRUNC_VOXELS = 4.0  # the signed distance is truncated at this many voxels


class TsdfMap:
    """A growing voxel-block TSDF volume: `add` frames, then `mesh`. Past MAX_BLOCKS the surface so far is kept as a
    mesh and a new volume takes the frames that follow (where the two meet, each holds its side of the surface)."""

    def __init__(self, settings: MapConfig) -> None:
        import open3d as o3d
        import open3d.core as o3c

        self.s = settings
        self._o3d, self._o3c = o3d, o3c
        self.parts: list = []  # the surfaces of the volumes that grew past MAX_BLOCKS
        self.grid = self._new_grid()
        self.frames = 0
        self.blocks_done = 0

    def _new_grid(self):
        o3d, o3c = self._o3d, self._o3c
        # weight and colour as uint16: the same surface (812k vertices of a rendered drive's first 40 frames, mean
        # position within 0.5 mm, colour within 0.3 %) in 12 bytes a voxel instead of 20
        return o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.uint16, o3c.uint16),
            attr_channels=((1), (1), (3)),
            voxel_size=self.s.voxel_m,
            block_resolution=8,
            block_count=20000,
            device=o3c.Device("CPU:0"),
        )

    def add(self, image: np.ndarray, depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> None:
        """Integrate one frame: RGB (or gray) uint8 image, depth in metres (0 = none), camera pose."""
        o3d, o3c = self._o3d, self._o3c
        self.frames += 1
        if not (depth > 0).any():  # nothing of this frame within reach (or certain enough)
            return
        rgb = np.dstack([image] * 3) if image.ndim == 2 else image
        colour = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, np.float32) / 255.0))
        d = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth, np.float32)))
        intr = o3c.Tensor(np.asarray(K, np.float64))
        extr = o3c.Tensor(np.linalg.inv(np.asarray(T_world_cam, np.float64)))
        kw = {"depth_scale": 1.0, "depth_max": self.s.max_depth_m, "trunc_voxel_multiplier": TRUNC_VOXELS}
        try:
            blocks = self.grid.compute_unique_block_coordinates(d, intr, extr, **kw)
        except RuntimeError as exc:  # Open3D samples the depth map sparsely: a few valid pixels may touch no block
            if "No block is touched" in str(exc):
                return
            raise
        self.grid.integrate(blocks, d, colour, intr, extr, **kw)
        if self._grid_blocks() > MAX_BLOCKS:
            self.blocks_done += self._grid_blocks()
            self.parts.append(self._surface())
            self.grid = self._new_grid()

    def _grid_blocks(self) -> int:
        return int(self.grid.hashmap().size())

    def _surface(self):
        if not self._grid_blocks():
            return self._o3d.geometry.TriangleMesh()
        return self.grid.extract_triangle_mesh(weight_threshold=self.s.min_weight).to_legacy()

    def mesh(self):
        """The surface as a legacy Open3D TriangleMesh with vertex colours (empty when nothing was fused)."""
        out = self._surface()
        for part in self.parts:
            out += part
        return out

    @property
    def blocks(self) -> int:
        """Voxel blocks allocated over the whole drive."""
        return self.blocks_done + self._grid_blocks()


EDGE_FOCAL_PX = 720.0  # `edge_jump` is the jump between neighbouring pixels of a camera of this focal length


def map_depth(
    depth: np.ndarray, sigma: np.ndarray | None, settings: MapConfig, focal_px: float = EDGE_FOCAL_PX
) -> np.ndarray:
    """The depth the map takes from a frame: 0 beyond the farthest depth, where sigma / depth is above
    `sigma_max` (sigma in metres, as written by `leovr refine`), and on depth edges: a pixel whose 3 x 3
    neighbourhood spans more than a factor 1 + `edge_jump` (for a camera of EDGE_FOCAL_PX; a coarser camera's
    pixel spans a wider angle, over which a steep surface changes more: the jump scales with it) lies between a
    foreground and a background, where a dense depth map's values are least certain (flying pixels) and a TSDF
    would draw a false surface."""
    keep = (depth > 0) & (depth <= settings.max_depth_m)
    if sigma is not None and settings.sigma_max is not None:
        keep &= sigma <= settings.sigma_max * depth
    if settings.edge_jump is not None:
        box = np.ones((3, 3), np.uint8)
        lo = cv2.erode(np.where(keep, depth, 1e9).astype(np.float32), box)
        hi = cv2.dilate(np.where(keep, depth, 0.0).astype(np.float32), box)
        keep &= hi <= (1.0 + settings.edge_jump * EDGE_FOCAL_PX / focal_px) * lo
    return np.where(keep, depth, 0.0).astype(np.float32)


def fuse_run(run: RunFolder, settings: MapConfig, source: str = "depth", progress: bool = True) -> TsdfMap:
    """The run's depth maps (folder `source`) fused with its images and poses; the uncertainty filter applies
    where the run wrote `sigma/`."""
    vol = TsdfMap(settings)
    with_sigma = settings.sigma_max is not None and (run.path / "sigma").is_dir()
    for n, i in enumerate(tqdm(run.indices, desc="map", unit="frame", disable=not progress)):
        frame = run.seq[i]
        depth = read_depth_png(run.png(source, n), shape=frame.shape)
        sigma = read_depth_png(run.png("sigma", n), SIGMA_SCALE, shape=frame.shape) if with_sigma else None
        vol.add(frame.image, map_depth(depth, sigma, settings, float(frame.K[0, 0])), frame.K, run.poses[n])
    return vol


def write_map(vol: TsdfMap, out: Path) -> dict:
    """map.ply (coloured mesh) and map_points.ply (its vertices) in `out`, each written atomically."""
    import open3d as o3d

    mesh = vol.mesh()
    if not len(mesh.triangles):
        raise DataError(out, "the map is empty: no depth within reach was fused (check --max-depth and --sigma-max)")
    # the volume's colour averages can pass 1 by a rounding step: clipped here, not by Open3D's writer (which
    # says so on stdout for every file)
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.clip(np.asarray(mesh.vertex_colors), 0.0, 1.0))
    cloud = o3d.geometry.PointCloud(mesh.vertices)
    cloud.colors = mesh.vertex_colors
    atomic_write(out / "map.ply", lambda tmp: _check(o3d.io.write_triangle_mesh(str(tmp), mesh), out / "map.ply"))
    atomic_write(
        out / "map_points.ply", lambda tmp: _check(o3d.io.write_point_cloud(str(tmp), cloud), out / "map_points.ply")
    )
    return {"vertices": len(mesh.vertices), "triangles": len(mesh.triangles)}


def _check(ok: bool, path: Path) -> None:
    if not ok:
        raise DataError(path, "could not be written")


def peak_memory_mb() -> float:
    """This process's peak resident memory so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def map_run(run_dir: Path, out: Path, settings: MapConfig, progress: bool = True) -> dict:
    """`leovr map`: fuse a finished refine run into `out` (map.ply, map_points.ply, map.json); returns map.json."""
    run = read_run(Path(run_dir))
    t0 = time.perf_counter()
    vol = fuse_run(run, settings, progress=progress)
    fused_s = time.perf_counter() - t0
    summary = {
        "run": str(Path(run_dir).resolve()),
        "out": str(Path(out).resolve()),
        "frames": vol.frames,
        "settings": settings.model_dump(),
        "uncertainty_filter": settings.sigma_max is not None and (run.path / "sigma").is_dir(),
        **write_map(vol, Path(out)),
        "blocks": vol.blocks,
        "seconds_per_frame": round(fused_s / max(vol.frames, 1), 4),
        "peak_memory_mb": round(peak_memory_mb(), 1),
    }
    write_text(Path(out) / "map.json", json.dumps(summary, indent=1) + "\n")
    return summary
