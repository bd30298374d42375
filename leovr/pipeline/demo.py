"""`leovr demo`: the README's main job. By default it renders a short Mid-40 sequence of the procedural
city (the embedded default), refines it with the shipped generator and the sliding-window graph, and
writes `metrics.json`, `report.md`, three plots (MAE per distance bin for the raw input, IP-Basic, the
generator and the refined depth; a top view of the trajectories; a top view of the 3D map fused from the refined
depth, `refine/map/`) and `demo.rrd` (Rerun, with the map). With `data`
it runs on a recorded sequence instead (a cheap input simulated from its scan, scored on held-out points).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from leovr.config import DemoConfig, LoopConfig, MapConfig, RefineConfig, SimulateConfig
from leovr.data import open_sequence
from leovr.data.io import atomic_write, write_text
from leovr.data.kitti_common import read_kitti_poses
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.geometry import invert_T
from leovr.pipeline.refine import run_refine
from leovr.pipeline.refine_input import completion_config, frame_sample
from leovr.pipeline.tsdf_map import map_run
from leovr.sim.simulate import simulate
from leovr.viz.recording import write_recording

# generator_frame: own scan alone (Mid-40)
METHODS = (
    "raw",
    "nearest",
    "ipbasic",
    "generator_frame",
    "generator",
    "refined",
)


def _fmt(v: float | None, digits: int = 3) -> str:
    return "-" if v is None or v != v else f"{v:.{digits}f}"


def raw_input_metrics(seq, cfg: RefineConfig, indices: list[int]) -> dict:
    """The LiDAR input itself, scored where it has a return (its noise and misalignment)."""
    acc = DepthMetricAccumulator(cfg.bins)
    ccfg = completion_config(cfg)
    for i in indices:
        s = frame_sample(seq, i, ccfg)
        acc.add(s.sparse, np.where(s.sparse > 0, s.gt, 0.0))
    return acc.result()


def plot_bins(depth: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = [m for m in METHODS if m in depth]
    bins = list(depth[methods[0]]["bins"])
    x = np.arange(len(bins))
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for k, m in enumerate(methods):
        vals = [depth[m]["bins"][b].get("mae_m") or np.nan for b in bins]
        ax.bar(x + (k - (len(methods) - 1) / 2) * 0.8 / len(methods), vals, 0.8 / len(methods), label=m)
    ax.set_xticks(x, [f"{b} m" for b in bins])
    ax.set_ylabel("MAE (m)")
    ax.set_title("Depth error by distance")
    ax.legend()
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)


def plot_trajectories(tracks: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    styles = {"ground_truth": ("k", "-"), "kiss_icp": ("tab:blue", "--"), "leovr": ("tab:orange", "-")}
    for name, xyz in tracks.items():
        c, ls = styles.get(name, ("gray", ":"))
        ax.plot(xyz[:, 0], xyz[:, 2], color=c, linestyle=ls, label=name, marker=".")
    ax.set_xlabel("x (m, right)")
    ax.set_ylabel("z (m, forward)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("Trajectories, top view (first camera frame)")
    ax.legend()
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)


def run_demo(out: Path, cfg: DemoConfig, progress: bool = True) -> dict:
    """Render (or open), refine, score, plot and record; returns the metrics written to metrics.json."""
    out = Path(out)
    if cfg.data:
        seq = open_sequence(cfg.data)
        inp = cfg.input or "mid40"
        source = f"recorded sequence `{seq.path}` ({seq.name})"
    else:
        sim = SimulateConfig(scenario=cfg.scenario, lidar=cfg.lidar, frames=cfg.frames, seed=cfg.seed)
        simulate(sim, out / "sequence", preview=True, progress=progress)
        seq = open_sequence(out / "sequence")
        inp = cfg.input or "full"
        source = (
            f"generated `{cfg.scenario}` sequence, {cfg.lidar} LiDAR, seed {cfg.seed} "
            f"(`{out / 'sequence'}`, preview in `sequence/preview.png`)"
        )
    # loop closure where the scenario has loops (a lap of the city loop takes about 290 frames at 30 km/h)
    rcfg = RefineConfig(
        input=inp, end=min(cfg.frames, len(seq)), loop=LoopConfig(enabled=not cfg.data and cfg.scenario == "city_loop")
    )
    m = run_refine(seq, rcfg, out / "refine", progress=progress)
    indices = list(range(rcfg.end))
    if seq.has_lidar:
        m["depth"] = {"raw": raw_input_metrics(seq, rcfg, indices), **m["depth"]}
    m["map"] = map_run(out / "refine", out / "refine" / "map", MapConfig(), progress=progress)
    write_text(out / "metrics.json", json.dumps(m, indent=2) + "\n")
    if m["depth"]:
        plot_bins(m["depth"], out / "mae_by_distance.png")
    tracks = {"leovr": read_kitti_poses(out / "refine" / "poses_kitti.txt")[:, :3, 3]}
    gt = [seq[i].T_world_cam for i in indices]
    if all(T is not None for T in gt):
        tracks["ground_truth"] = np.stack([(invert_T(gt[0]) @ T)[:3, 3] for T in gt])
    if (out / "refine" / "poses_kiss_icp_kitti.txt").is_file():
        tracks["kiss_icp"] = read_kitti_poses(out / "refine" / "poses_kiss_icp_kitti.txt")[:, :3, 3]
    plot_trajectories(tracks, out / "trajectory.png")
    plot_map(out / "refine" / "map" / "map_points.ply", out / "map.png")
    write_recording(out / "refine", out / "demo.rrd")
    write_text(out / "report.md", report(m, source, inp))
    return m


def plot_map(points_ply: Path, path: Path) -> None:
    """A top view of the map's coloured points (x right, z forward), the nearest point over each spot on top."""
    import matplotlib
    import open3d as o3d

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cloud = o3d.io.read_point_cloud(str(points_ply))
    xyz, rgb = np.asarray(cloud.points), np.asarray(cloud.colors)
    order = np.argsort(-xyz[:, 1])  # y points down: the highest points are drawn last, on top
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.scatter(xyz[order, 0], xyz[order, 2], c=rgb[order], s=0.5, marker=".", linewidths=0)
    ax.set_xlabel("x (m, right)")
    ax.set_ylabel("z (m, forward)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("3D map (TSDF mesh vertices), top view")
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)


def report(m: dict, source: str, inp: str) -> str:
    depth = m["depth"]
    bins = list(next(iter(depth.values()))["bins"]) if depth else []
    lines = [
        "# leovr demo: refinement report",
        "",
        f"Input: {source}; {m['frames']} frames; LiDAR input `{inp}`; {m['mode']}; window {m['window']}.",
        f"Ground truth: {m['ground_truth'] or 'none'}. `raw` is the LiDAR input scored where it has a return.",
        *(
            [
                "`generator_frame` is the generator on each frame's own scan; `generator` had the returns of the "
                "earlier frames added (a Mid-40 cone: `refine.accumulation.frames`) and was moved towards image "
                "corners triangulated over the frames around it (`refine.motion_stereo.enabled`, on for a cone by "
                "default), as the graph used it; `refined` is also moved, where no return lies, by a photometric "
                "plane sweep against the frames +-1..3 when the poses pass its check (`refine.photometric.enabled`). "
                "`nearest_accumulated` and `ipbasic_accumulated` fill the cheap returns of the same frames (16 before "
                "and after), placed with KISS-ICP's poses: the fair yardstick for "
                "a refinement that sees several frames."
            ]
            if "generator_frame" in depth
            else []
        ),
        "",
        "| method | MAE (m) | RMSE (m) | AbsRel | delta<1.25 | " + " | ".join(f"MAE {b} m" for b in bins) + " |",
        "|---" * (5 + len(bins)) + "|",
    ]
    for method, r in depth.items():
        per_bin = " | ".join(_fmt(r["bins"][b].get("mae_m")) for b in bins)
        lines.append(
            f"| {method} | {_fmt(r['mae_m'])} | {_fmt(r['rmse_m'])} | {_fmt(r['absrel'])} | {_fmt(r['delta1'])} "
            f"| {per_bin} |"
        )
    if "trajectory" in m:
        lines += ["", "| trajectory | ATE (m) | RPE (m/frame) | alignment |", "|---|---|---|---|"]
        for name, t in m["trajectory"].items():
            lines.append(f"| {name} | {t['ate_m']:.3f} | {t['rpe_m']:.3f} | {t['align']} |")
        if "kiss_icp" in m["trajectory"]:
            lines += [
                "",
                "`kiss_icp` is KISS-ICP alone on the same LiDAR input, deskewing the raw scans itself from their "
                "point times (`refine/poses_kiss_icp_kitti.txt`); a Mid-40's 38-degree cone constrains it poorly."
                + (
                    " `kiss_icp_no_deskew`: the same without its deskew."
                    if "kiss_icp_no_deskew" in m["trajectory"]
                    else ""
                ),
            ]
    if (Path(m["sequence"]).parent / "refine" / "loops.json").is_file():
        loops = json.loads((Path(m["sequence"]).parent / "refine" / "loops.json").read_text())["loops"]
        lines += [
            "",
            f"Loop closure: {sum(r['accepted'] for r in loops)} loops accepted of {len(loops)} candidates "
            "(`refine/loops.json`; a lap of the city loop needs about 290 frames at 30 km/h).",
        ]
    t = m["timing"]
    lines += [
        "",
        f"Time per frame: generator {t['generator_ms']:.0f} ms, front end {t['frontend_ms']:.0f} ms, "
        f"graph {t['graph_ms']:.0f} ms"
        + (
            f", {t['stats']['wall_ms']['median']:.0f} ms end to end (median; the generator runs beside the graph)"
            if "wall_ms" in t.get("stats", {})
            else ""
        )
        + "; "
        f"initial poses: {t['initial_pose_sources']}.",
        "",
        f"Map: {m['map']['frames']} frames fused into {m['map']['triangles']} triangles "
        f"({m['map']['seconds_per_frame'] * 1000:.0f} ms a frame): `refine/map/map.ply`, top view in `map.png`.",
        "",
        "Files: `refine/depth/` (refined, uint16 metres x 256), `refine/depth_generator/`, `refine/poses_kitti.txt`, "
        "`refine/poses_tum.txt`, `refine/map/`, `mae_by_distance.png`, `trajectory.png`, `map.png`, `demo.rrd` "
        "(open with `rerun demo.rrd`).",
        "",
    ]
    return "\n".join(lines)
