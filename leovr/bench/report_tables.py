"""Formatting helpers and shared tables of docs/benchmarks.md: numbers, ratios, commands, depth and trajectory
tables (leovr.bench.report)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any


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
    if Path(words[0]).name == "leovr" or words[0] == "-c":
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
                    " / ".join(num(a) for a in r.get("ate_per_stretch_m") or []) or "-",
                    num(r.get("kitti_t_err_pct"), 2),
                    num(r.get("ate_gps_fixes_m")),
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
        "ATE per 32 frames (m)",
        "KITTI drift (%)",
        "ATE vs GPS fixes (m)",
        "alignment",
        "leovr ÷ this (ATE)",
    ]
    for col in (10, 9, 8, 7, 5, 4, 3):  # drop what no run recorded (alignment; the ATE's parts)
        if all(r[col] == "-" for r in rows):
            head, rows = head[:col] + head[col + 1 :], [r[:col] + r[col + 1 :] for r in rows]
    return table(head, rows)
