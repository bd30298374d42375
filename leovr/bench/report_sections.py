"""One renderer per benchmark for docs/benchmarks.md: each turns a bench's JSON into its data lines and its
tables (leovr.bench.report puts them under their headers)."""

from __future__ import annotations

from pathlib import Path

from leovr.bench.report_tables import (
    bins_table,
    depth_table,
    get,
    listing,
    methods,
    num,
    ratio,
    refs,
    table,
    traj_table,
)


def render_baseline(doc: dict) -> tuple[list[str], list[str]]:
    """Classical fills per input, and per distance bin."""
    data = [
        f"KITTI raw clip `{doc.get('sequence', '-')}`, {doc.get('frames', '-')} frames; "
        f"ground truth: {doc.get('ground_truth', '-')}"
    ]
    groups = doc.get("results") or {}
    return data, depth_table(groups, ["nearest"]) + bins_table(groups, ["nearest"])


def render_depth(doc: dict) -> tuple[list[str], list[str]]:
    """Every method per data set, the generator's uncertainty and time, MAE per distance bin."""
    gt = doc.get("ground_truth") if isinstance(doc.get("ground_truth"), dict) else {}
    data = [
        f"rendered test sequences in `{doc.get('synthetic_dataset', '-')}` ({doc.get('synthetic_input', '-')}); "
        f"ground truth: {gt.get('synthetic', '-')}",
        f"KITTI raw `{doc.get('kitti_sequence', '-')}`; ground truth: {gt.get('kitti', '-')}",
    ]
    groups, summary = doc.get("results") or {}, doc.get("summary") or {}
    ref_names = refs(groups, summary)
    body = depth_table(groups, ref_names)
    sig = [
        [
            label,
            num(get(ms, "generator", "uncertainty", "spearman_error_sigma"), 2),
            num(get(summary, label, "generator_time_vs_ipbasic"), 2, "x"),
        ]
        for label, ms in groups.items()
    ]
    body += ["How well the generator's predicted sigma ranks its errors (Spearman correlation), and its time:", ""]
    body += table(["data", "Spearman of error and sigma", "generator time ÷ ipbasic"], sig)
    return data, body + bins_table(groups, ref_names)


def render_refine(doc: dict) -> tuple[list[str], list[str]]:
    """Depth before and after the graph, trajectories, time per stage, the window ablation."""
    names = sorted(
        {
            s
            for ms in (doc.get("results") or {}).values()
            for r in methods(ms).values()
            for s in (r.get("per_sequence_mae_m") or {})
        }
    )
    data = [
        f"rendered test sequences in `{doc.get('synthetic_dataset', '-')}`: {listing(names)}; "
        f"window {doc.get('window', '-')} frames, frames per sequence: {doc.get('frames_per_sequence') or 'all'}"
    ]
    kitti = [k for k in (doc.get("results") or {}) if k.startswith("kitti")]
    odo = [k for k in (doc.get("trajectory") or {}) if k not in (doc.get("results") or {}) and k.startswith("kitti")]
    data += [
        f"KITTI: depth on {listing(kitti)} (cheap inputs simulated from the HDL-64 scan)"
        + (f"; trajectories also on {listing(odo)} (camera only)" if odo else "")
    ]
    dev = doc.get("kitti_raw_development")
    if isinstance(dev, dict):
        data += [f"KITTI raw `{k}`: {'development data' if v else 'not development data'}" for k, v in dev.items()]
    groups = doc.get("results") or {}
    body = depth_table(groups, ["nearest"]) + bins_table(groups, ["nearest"])
    body += ["Trajectories (synthetic: means over the sequences):", ""] + traj_table(doc.get("trajectory") or {})
    timing = doc.get("timing") or {}
    body += ["Mean time per frame and stage over every run (ms):", ""]
    body += table(list(timing), [[num(v, 1) for v in timing.values()]])
    abl = get(doc, "window_ablation", "results") or {}
    rows = [
        [
            w + (" (above)" if str(doc.get("window")) == w else ""),
            num(r.get("generator_mae_m")),
            num(r.get("refined_mae_m")),
            num(r.get("ate_m")),
            num(r.get("graph_ms"), 1),
        ]
        for w, r in abl.items()
    ]
    seq = Path(str(get(doc, "window_ablation", "sequence") or "-")).name
    body += [f"Window length on `{seq}`:", ""] if rows else []
    return data, body + table(["window", "generator MAE (m)", "refined MAE (m)", "ATE (m)", "graph ms"], rows)


def render_real(doc: dict) -> tuple[list[str], list[str]]:
    """Depth per clip and pooled (with development flags), and trajectories where a clip has poses."""
    clips = doc.get("clips") or {}
    dev = {True: "development data (used while developing leovr, not held out)", False: "not development data"}
    data = [
        f"`{name}` ({c.get('frames', '-')} frames, {'with' if c.get('has_poses') else 'no'} poses): "
        + dev.get(c.get("development"), "development: -")
        for name, c in clips.items()
    ]
    data += [f"ground truth: {doc.get('ground_truth', '-')}"]
    data += [f"ground truth: {doc['ground_truth_poses']}"] if doc.get("ground_truth_poses") else []
    groups = {f"{name}, {inp}": g for name, c in clips.items() for inp, g in (c.get("results") or {}).items()}
    pooled = get(doc, "pooled", "results") or {}
    groups.update({f"pooled, {inp}": g for inp, g in pooled.items()})
    summaries = {f"{name}, {inp}": s for name, c in clips.items() for inp, s in (c.get("summary") or {}).items()}
    summaries.update({f"pooled, {inp}": s for inp, s in (get(doc, "pooled", "summary") or {}).items()})
    ref_names = refs(groups, summaries)
    body = ["`shipped_<input>`: the shipped network. Pooled: every scored pixel of every clip.", ""]
    body += depth_table(groups, ref_names) + bins_table(
        {k: v for k, v in groups.items() if k.startswith("pooled")}, ref_names
    )
    traj = {f"{name}, {inp}": t for name, c in clips.items() for inp, t in (c.get("trajectory") or {}).items()}
    return data, body + (["Trajectories:", ""] + traj_table(traj) if traj else [])


def render_loop(doc: dict) -> tuple[list[str], list[str]]:
    """Loops accepted / true / false / missed and the ATE with and without them, per lap and clip."""
    data = [
        f"rendered `city_loop` laps at {num(doc.get('speed_kmh'), 0)} km/h, "
        f"{doc.get('frames_per_synthetic_sequence', '-')} frames, seeds {listing(doc.get('seeds'))} "
        f"(thresholds tuned on seeds {listing(doc.get('tuning_seeds'))}); loops at least "
        f"{doc.get('loop_min_gap', '-')} frames apart; real clips have no revisits",
        f"vocabulary: {get(doc, 'vocabulary', 'words') or '-'} words from "
        f"{get(doc, 'vocabulary', 'images') or '-'} images ("
        f"{'trained with' if get(doc, 'vocabulary', 'real_clips_seen') else 'never saw'} the real clips)",
    ]
    rows = []
    for suffix, key in (("", "results"), (" (tuning)", "tuning_results")):
        for name, r in (doc.get(key) or {}).items():
            errs = [e["error_m"] for e in r.get("accepted_errors") or [] if isinstance(get(e, "error_m"), (int, float))]
            mean_err = sum(errs) / len(errs) if errs else None
            rows.append(
                [name + suffix]
                + [
                    str(r.get(k, "-"))
                    for k in ("loops_accepted", "loops_true", "loops_false", "loops_missed", "revisit_frames")
                ]
                + [
                    num(mean_err),
                    num(r.get("ate_no_loop_m")),
                    num(r.get("ate_loop_m")),
                    ratio(r.get("ate_loop_m"), r.get("ate_no_loop_m")),
                    num(r.get("ate_ideal_loops_m")),
                    ratio(r.get("ate_loop_m"), r.get("ate_ideal_loops_m")),
                    num(r.get("ms_per_query"), 1),
                ]
            )
    head = [
        "data",
        "accepted",
        "true",
        "false",
        "missed",
        "revisit frames",
        "mean loop error (m)",
        "ATE no loops (m)",
        "ATE with loops (m)",
        "with ÷ no loops",
        "ATE ideal loops (m)",
        "with ÷ ideal loops",
        "ms/query",
    ]
    note = [
        "A loop is true when its relative pose is within 1 m and 5 degrees of the truth; a revisit frame with no "
        "accepted loop within 5 frames is missed. Loop error: mean translation error of the accepted loops. "
        "Ideal loops: the same pose graph given the true relative poses at the accepted loops' frame pairs.",
        "",
    ]
    return data, table(head, rows) + (note if rows else [])


def render_speed(doc: dict) -> tuple[list[str], list[str]]:
    """Milliseconds per stage, end-to-end speed with its accuracy, and the speed targets."""
    res = doc.get("results") or {}
    data = [
        f"`{k}`: {r.get('frames', '-')} frames, {r.get('width', '-')}x{r.get('height', '-')}, "
        f"input `{r.get('input', '-')}`"
        for k, r in res.items()
    ]
    stages = list(dict.fromkeys(s for r in res.values() for s in (r.get("ms_per_frame") or {})))
    rows = [
        [s]
        + [
            " / ".join(num(get(r, "ms_per_frame", s, q), 1) for q in ("median", "p95", "max"))
            + f" ({num(get(r, 'growth', s), 2, 'x')})"
            for r in res.values()
        ]
        for s in stages
    ]
    body = [
        "Milliseconds per frame, median / p95 / max, and in brackets the growth along the drive (median over "
        "the last quarter of the frames ÷ over the second quarter):",
        "",
    ]
    body += table(["stage"] + list(res), rows)
    rows = [
        [
            k,
            num(get(r, "ms_per_frame", "wall_ms", "median"), 0),
            num(get(r, "ms_per_frame", "cpu_ms", "median"), 0),
            num(r.get("fps_wall"), 2),
            num(r.get("ipbasic_ms_per_frame"), 1),
            num(r.get("wall_over_ipbasic"), 1, "x"),
            num(get(r, "mae_m", "nearest")),
            num(get(r, "mae_m", "refined")),
            num(get(r, "ate_m", "leovr")),
            num(get(r, "ate_m", "kiss_icp")),
        ]
        for k, r in res.items()
    ]
    body += [
        "End to end: a frame's wall time and the CPU time of all its threads (medians), the run's frames per "
        "second with reading, scoring and writing, and the same run's accuracy:",
        "",
    ]
    body += table(
        [
            "data",
            "wall ms/frame",
            "CPU ms/frame",
            "fps (run)",
            "ipbasic ms/frame",
            "wall ÷ ipbasic",
            "nearest MAE (m)",
            "refined MAE (m)",
            "leovr ATE (m)",
            "kiss_icp ATE (m)",
        ],
        rows,
    )
    targets = [f"`{k}` {'met' if v else 'not met'}" for k, v in (doc.get("targets_met") or {}).items()]
    return data, body + ([f"Targets: {', '.join(targets)}.", ""] if targets else [])


def render_batch(doc: dict) -> tuple[list[str], list[str]]:
    """Wall time per worker count and the speedup."""
    s = doc.get("settings") or {}
    data = [
        f"{doc.get('sequences', '-')} rendered sequences, {doc.get('frames', '-')} frames in all, "
        f"{s.get('lidar', '-')} input, {s.get('cpus_per_task', '-')} CPU per task, refine {s.get('refine', '-')}"
    ]
    wall, tasks, fixed = (doc.get(k) or {} for k in ("wall_s", "task_s_sum", "fixed_s"))
    rows = [[w, num(wall.get(w), 1), num(tasks.get(w), 1), num(fixed.get(w), 1)] for w in wall]
    body = table(["workers", "wall (s)", "sum of task times (s)", "fixed cost (s)"], rows)
    met = get(doc, "targets_met", "speedup")
    body += [
        f"Speedup {num(doc.get('speedup'), 2, 'x')} (target {num(doc.get('target_speedup'), 2, 'x')}, "
        f"{'met' if met else 'not met' if met is not None else '-'}; ceiling "
        f"{num(doc.get('ceiling_speedup'), 2, 'x')}); {num(doc.get('frames_per_core_hour'), 0)} frames per core "
        "hour.",
        "",
    ]
    return data, body


def render_simulate(doc: dict) -> tuple[list[str], list[str]]:
    """Frames per second per LiDAR model."""
    data = [f"scenario `{doc.get('scenario', '-')}`, {doc.get('width', '-')}x{doc.get('height', '-')} pixels"]
    rows = [
        [
            lidar,
            str(r.get("frames", "-")),
            num(r.get("frames_per_s"), 2),
            num(r.get("render_s_per_frame")),
            num(r.get("wall_s_per_frame_with_writing")),
        ]
        for lidar, r in (doc.get("per_lidar") or {}).items()
    ]
    return data, table(["LiDAR", "frames", "frames/s", "render s/frame", "s/frame with writing"], rows)


def render_map(doc: dict) -> tuple[list[str], list[str]]:
    """Accuracy and completeness of each map per clip and input, the uncertainty sweep, cost."""
    res = doc.get("results") or {}
    dev = {True: "development data", False: "not development data"}
    data = [
        f"`{k}`: {r.get('frames', '-')} frames, held-out returns placed with the {r.get('poses', '-')} poses, "
        f"{dev.get(r.get('development'), '-')}"
        for k, r in res.items()
    ]
    data += [
        f"accuracy: mean distance of the held-out returns to the map where within {doc.get('cover_m', '-')} m; "
        f"completeness: share within {doc.get('near_m', '-')} m"
    ]
    rows = []
    for k, r in res.items():
        m, s = r.get("maps") or {}, (doc.get("summary") or {}).get(k) or {}
        rows.append(
            [k]
            + [
                f"{num(get(m, name, 'accuracy_m'))} / {num(get(m, name, 'completeness'))}"
                for name in ("refined", "nearest", "accumulated")
            ]
            + [
                num(s.get("accuracy_vs_nearest"), 2, "x"),
                num(s.get("completeness_vs_accumulated"), 2, "x"),
                num(r.get("seconds_per_frame")),
                num(r.get("peak_memory_mb"), 0),
            ]
        )
    body = table(
        [
            "clip, input",
            "refined acc. m / compl.",
            "nearest",
            "accumulated",
            "nearest acc. ÷ refined",
            "refined compl. ÷ accumulated",
            "fusion s/frame",
            "peak MB",
        ],
        rows,
    )
    sweep = sorted({n for r in res.values() for n in (r.get("maps") or {}) if n.startswith("refined_sigma_")})
    if sweep:
        body += ["", "The refined map at each uncertainty threshold (`--sigma-max`; accuracy m / completeness):", ""]
        body += table(
            ["clip, input"] + [n.removeprefix("refined_sigma_") for n in sweep],
            [
                [k]
                + [f"{num(get(r, 'maps', n, 'accuracy_m'))} / {num(get(r, 'maps', n, 'completeness'))}" for n in sweep]
                for k, r in res.items()
            ],
        )
    return data, body
