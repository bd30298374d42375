"""Render docs/benchmarks.md from the benchmark JSON files (`python tools/gen_docs.py` writes it).

Only the current result of each bench is read (`<results_dir>/<name>.json`); a missing file gets a one-line
note. Unknown keys are ignored, unknown depth or trajectory methods become extra rows, missing values "-".
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

BENCHES: dict[str, str] = {
    "baseline": "Classical depth completion (nearest fill, IP-Basic) on the KITTI raw clip, both cheap inputs.",
    "depth": "Depth per method, leovr's generator against classical fills, on rendered sequences and KITTI raw.",
    "refine": "The `leovr refine` pipeline: depth before and after the graph, trajectories, time, window length.",
    "real": "Depth on each real KITTI raw drive, every method on the same pixels, and trajectories against KISS-ICP.",
    "loop": "Loop closure on rendered laps (true, false, missed loops; ATE with and without them) and real clips.",
    "speed": "Where `leovr refine` spends its time per frame, and its accuracy in the same run.",
    "batch": "Wall time of `leovr batch` with 1 and 2 workers on the same rendered sequences.",
    "selfsup": "Cold-start self-supervised training against a supervised reference, with movers, and on KITTI raw.",
    "simulate": "Rendering speed of the simulator (camera, depth and LiDAR) per LiDAR model.",
    "map": "3D maps of each real drive fused from refined depth, the nearest fill and the accumulated cheap returns.",
}

GLOSSARY = [
    "Reading the tables:",
    "",
    "- Inputs: `mid40` is a Livox Mid-40-like cone LiDAR, `vlp16` a VLP-16-like spinning LiDAR; on KITTI both are "
    "simulated from the HDL-64 scan and scored on its held-out returns. `synthetic_*`: rendered test sequences.",
    "- Depth methods: `nearest` (nearest-return fill), `ipbasic` (IP-Basic), `interp` (the generator's classical "
    "prior alone), `generator` (leovr's network; in refine and real with a cone LiDAR also fed the earlier scans), "
    "`generator_frame` (the frame's own scan only), `refined` (after the graph), `*_accumulated` (the fill on the "
    "same frames' returns placed with KISS-ICP's poses).",
    "- Trajectories: `leovr`, `leovr_no_loop` (before loop closure), `kiss_icp` (KISS-ICP on the same LiDAR input), "
    "`kiss_icp_no_deskew` (without its deskew), `mono_vo` (textbook monocular VO, Sim(3)-aligned).",
    "- MAE, RMSE, ATE (RMSE of the aligned positions; lateral, vertical, forward: its parts along the true "
    "camera's x, y, z axes) and RPE (frame to frame) in metres; AbsRel = mean "
    "|error| / depth; delta1 = share of pixels within 1.25x of the truth. `A ÷ B` ratios below 1.00x favour A.",
]


def get(d: Any, *path: str) -> Any:
    """`d[path[0]][path[1]]...`, or None where a key is missing or a level is not a dict."""
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def num(v: Any, decimals: int = 3, suffix: str = "") -> str:
    """A number with `decimals` decimals (and `suffix`), "-" for anything that is not a number."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return "-"
    return f"{v:.{decimals}f}{suffix}"


def ratio(a: Any, b: Any) -> str:
    """a / b as "0.57x", "-" when either is missing or b is zero."""
    return num(a / b, 2, "x") if "-" not in (num(a), num(b)) and b else "-"


def table(head: list[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table (followed by a blank line); nothing when there are no rows."""
    if not rows:
        return []
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    return lines + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows] + [""]


def command(name: str, cmd: Any) -> str:
    """The bench's command as a user types it: `leovr bench ...` with `--out docs/results/<name>.json`."""
    words = str(cmd).split() if cmd else ["leovr", "bench", name]
    if Path(words[0]).name == "leovr":
        words[0] = "leovr"
    words = [w for w in words if not w.startswith("--out=")]
    if "--out" in words:
        i = words.index("--out")
        del words[i : i + 2]
    return " ".join(words + ["--out", f"docs/results/{name}.json"])


def listing(xs: Any) -> str:
    """The items of a list joined by commas, "-" for an empty or missing one."""
    return ", ".join(str(x) for x in xs) if isinstance(xs, list) and xs else "-"


def duration(s: Any) -> str:
    """Seconds, with minutes beside them past two minutes."""
    if not isinstance(s, (int, float)):
        return "-"
    return f"{s:.1f} s" if s < 120 else f"{s:.0f} s ({s / 60:.1f} min)"


def header(name: str, doc: dict, data: list[str]) -> list[str]:
    """Heading, the one-sentence purpose and the provenance bullets of a section."""
    m = doc.get("machine") if isinstance(doc.get("machine"), dict) else {}
    machine = ", ".join(
        x for x in (m.get("platform"), m.get("processor"), f"Python {m['python']}" if m.get("python") else None) if x
    )
    run = f"- Run: {doc.get('date_utc', '-')}, {duration(doc.get('duration_s'))}"
    run += f", leovr {doc['leovr_version']}" if doc.get("leovr_version") else ""
    run += f", commit `{doc['commit'] or 'unknown'}`" if "commit" in doc else ""
    run += ", `--quick` run" if doc.get("quick") else ""
    lines = [f"## {name}", "", BENCHES[name], "", f"- Command: `{command(name, doc.get('command'))}`", run]
    lines += [f"- Machine: {machine}"] if machine else []
    return lines + [f"- Data: {d}" for d in data] + [""]


def methods(group: Any, prefix: str = "") -> dict[str, dict]:
    """The depth methods of a group (dicts with `mae_m`), sub-dicts of methods flattened as `sub/method`."""
    out: dict[str, dict] = {}
    for key, val in group.items() if isinstance(group, dict) else []:
        if isinstance(val, dict) and "mae_m" in val:
            out[prefix + key] = val
        elif isinstance(val, dict) and not prefix:
            out.update(methods(val, f"{key}/"))
    return out


def refs(groups: dict[str, dict], summaries: dict[str, Any]) -> list[str]:
    """The reference methods for the ratio columns: those named in a summary's `*_vs_<ref>` keys, else nearest."""
    found: list[str] = []
    for label, summary in summaries.items():
        for key in summary if isinstance(summary, dict) else []:
            m = re.search(r"_vs_([a-z0-9_]+)$", key)
            if m and m.group(1) in methods(groups.get(label)) and m.group(1) not in found:
                found.append(m.group(1))
    return found or ["nearest"]


def depth_table(groups: dict[str, Any], ref_names: list[str]) -> list[str]:
    """One row per data set and method: MAE, RMSE, AbsRel, delta1, ms/frame where measured, MAE ratios."""
    per = {label: methods(g) for label, g in groups.items()}
    timed = any(isinstance(r.get("ms_per_frame"), (int, float)) for ms in per.values() for r in ms.values())
    head = ["data", "method", "MAE (m)", "RMSE (m)", "AbsRel", "delta1"] + (["ms/frame"] if timed else [])
    head += [f"MAE ÷ {r}" for r in ref_names]
    rows = []
    for label, ms in per.items():
        for i, (name, r) in enumerate(ms.items()):
            row = [
                label if i == 0 else "",
                name,
                num(r.get("mae_m")),
                num(r.get("rmse_m")),
                num(r.get("absrel")),
                num(r.get("delta1")),
            ] + ([num(r.get("ms_per_frame"), 1)] if timed else [])
            rows.append(row + [ratio(r.get("mae_m"), get(ms, ref, "mae_m")) for ref in ref_names])
    return table(head, rows)


def bins_table(groups: dict[str, Any], ref_names: list[str]) -> list[str]:
    """MAE per ground-truth distance bin for the reference methods and the pipeline's output (refined or generator)."""
    per = {label: methods(g) for label, g in groups.items()}
    bins = next((list(r["bins"]) for ms in per.values() for r in ms.values() if isinstance(r.get("bins"), dict)), [])
    rows = []
    for label, ms in per.items():
        output = next((m for m in ("refined", "generator") if m in ms), next(reversed(ms), None))  # the pipeline's
        for i, name in enumerate(dict.fromkeys(m for m in [*ref_names, output] if m in ms)):
            rows.append([label if i == 0 else "", name] + [num(get(ms[name], "bins", b, "mae_m")) for b in bins])
    if not bins:
        return []
    return ["MAE (m) per ground-truth distance bin (m):", ""] + table(["data", "method"] + bins, rows)


def alignment(r: dict) -> str:
    """ "Sim(3), scale 0.95" / "SE(3)" from a trajectory record (its own keys or its first sequence's)."""
    align = r.get("align") or get((r.get("per_sequence") or [{}])[0], "align")
    name = {"se3": "SE(3)", "sim3": "Sim(3)"}.get(str(align), "-")
    return f"{name}, scale {r['scale']:.2f}" if name == "Sim(3)" and isinstance(r.get("scale"), float) else name


AXES = ("lateral", "vertical", "forward")  # the ATE's parts along the reference camera's x, y, z


def traj_table(groups: dict[str, Any]) -> list[str]:
    """ATE (and its lateral / vertical / forward parts where recorded) and RPE per data set and trajectory
    method, leovr's ATE as a ratio of each baseline's."""
    rows = []
    for label, g in groups.items():
        ms = {k: v for k, v in (g.items() if isinstance(g, dict) else []) if isinstance(v, dict) and "ate_m" in v}
        known = ("kiss_icp", "kiss_icp_no_deskew", "mono_vo")  # leovr's rows first, then these, then the rest
        order = sorted(ms, key=lambda k: (not k.startswith("leovr"), known.index(k) if k in known else 9))
        for i, name in enumerate(order):
            r = ms[name]
            vs = "" if name.startswith("leovr") else ratio(get(ms, "leovr", "ate_m"), r.get("ate_m"))
            rows.append(
                [
                    label if i == 0 else "",
                    name,
                    num(r.get("ate_m")),
                    *(num(r.get(f"ate_{axis}_m")) for axis in AXES),
                    num(r.get("rpe_m")),
                    alignment(r),
                    vs,
                ]
            )
    head = [
        "data",
        "method",
        "ATE (m)",
        *(f"{axis} (m)" for axis in AXES),
        "RPE (m)",
        "alignment",
        "leovr ÷ this (ATE)",
    ]
    for col in (7, 5, 4, 3):  # drop what no run recorded (alignment; the ATE's parts)
        if all(r[col] == "-" for r in rows):
            head, rows = head[:col] + head[col + 1 :], [r[:col] + r[col + 1 :] for r in rows]
    return table(head, rows)


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
    groups = {f"{name}, {inp}": g for name, c in clips.items() for inp, g in (c.get("results") or {}).items()}
    pooled = get(doc, "pooled", "results") or {}
    groups.update({f"pooled, {inp}": g for inp, g in pooled.items()})
    summaries = {f"{name}, {inp}": s for name, c in clips.items() for inp, s in (c.get("summary") or {}).items()}
    summaries.update({f"pooled, {inp}": s for inp, s in (get(doc, "pooled", "summary") or {}).items()})
    ref_names = refs(groups, summaries)
    body = ["`shipped_<input>`: the shipped network, no adaptation. Pooled: every scored pixel of every clip.", ""]
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
                    num(r.get("ate_ideal_loops_m")),
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
        "ATE ideal loops (m)",
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


def render_selfsup(doc: dict) -> tuple[list[str], list[str]]:
    """Self-supervised against supervised, the masks on the traffic scenario, the KITTI cold start."""
    res = doc.get("results") or {}
    data = [
        f"training: {listing(doc.get('train_sequences'))}; test: {listing(doc.get('test_sequences'))}; "
        f"{doc.get('epochs', '-')} epochs",
        f"traffic: training {listing(doc.get('traffic_train_sequences'))}; test "
        f"{listing(doc.get('traffic_test_sequences'))}",
    ]
    minutes, dyn = res.get("train_minutes") or {}, res.get("dynamic_only") or {}
    syn = res.get("synthetic_metrics") or {}
    rows = [
        [
            m,
            num(r.get("mae_m")),
            num(r.get("rmse_m")),
            num(r.get("absrel")),
            num(r.get("delta1")),
            num(dyn.get(m)),
            ratio(r.get("mae_m"), get(syn, "supervised", "mae_m")),
            num(minutes.get(m), 1),
        ]
        for m, r in syn.items()
    ]
    body = table(
        ["model", "MAE (m)", "RMSE (m)", "AbsRel", "delta1", "dynamic only MAE (m)", "MAE ÷ supervised", "train min"],
        rows,
    )
    body += (
        [
            "`nomask`: without the photometric masks; `no_lf_lr`: without the L_f and L_r losses; `supervised`: "
            "trained on ground truth with the same frames, schedule and network.",
            "",
        ]
        if rows
        else []
    )
    tr = {k: v for k, v in (res.get("traffic_only") or {}).items() if not k.endswith("_gain")}
    rows = [[m, num(v), ratio(v, tr.get("selfsup_nomask")), num(minutes.get(f"traffic_{m}"), 1)] for m, v in tr.items()]
    body += [
        "`traffic` scenario (movers along the epipolar lines; `eq19_only`: the LeoVR paper's eq. 19 test alone; "
        "`oracle_mask`: the true moving mask, a bound):",
        "",
    ]
    body += table(["model", "MAE (m)", "MAE ÷ selfsup_nomask", "train min"], rows)
    k = res.get("kitti_raw") or {}
    rows = [
        [m] + [num(r.get(x)) for x in ("mae_m", "rmse_m", "absrel", "delta1")]
        for m, r in (k.get("held_out") or {}).items()
    ]
    body += (
        [
            f"KITTI raw cold start ({k.get('input', '-')} input, {k.get('train_frames', '-')} training frames, "
            f"{k.get('test_frames', '-')} held-out frames, {k.get('epochs', '-')} epochs):",
            "",
        ]
        if rows
        else []
    )
    return data, body + table(["model", "MAE (m)", "RMSE (m)", "AbsRel", "delta1"], rows)


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


RENDERERS = {
    "baseline": render_baseline,
    "depth": render_depth,
    "refine": render_refine,
    "real": render_real,
    "loop": render_loop,
    "speed": render_speed,
    "batch": render_batch,
    "selfsup": render_selfsup,
    "simulate": render_simulate,
    "map": render_map,
}


def section(name: str, doc: dict) -> str:
    """One bench's section as docs/benchmarks.md shows it (also what `leovr bench NAME` prints)."""
    data, body = RENDERERS[name](doc)
    return "\n".join(header(name, doc, data) + body).rstrip() + "\n"


def render(results_dir: Path) -> str:
    """docs/benchmarks.md: a preamble, then one section per bench from `<results_dir>/<name>.json`."""
    lines = (
        [
            "# Benchmarks",
            "",
            "Generated by `python tools/gen_docs.py` from docs/results/*.json; do not edit by hand.",
            "Rerun a bench with `leovr bench NAME --out docs/results/NAME.json`, then `python tools/gen_docs.py`.",
            "",
            "Sections: " + " · ".join(f"[{n}](#{n})" for n in BENCHES),
            "",
        ]
        + GLOSSARY
        + [""]
    )
    for name, render_one in RENDERERS.items():
        path = Path(results_dir) / f"{name}.json"
        if not path.is_file():
            lines += [f"## {name}", "", f"No result: `docs/results/{name}.json` is missing.", ""]
            continue
        try:
            doc = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not valid JSON ({e})") from e
        data, body = render_one(doc)
        lines += header(name, doc, data) + body
    return "\n".join(lines).rstrip() + "\n"
