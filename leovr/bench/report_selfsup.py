"""The renderer of `leovr bench selfsup`'s section of docs/benchmarks.md (the others: leovr.bench.report_sections)."""

from __future__ import annotations


from leovr.bench.report_tables import (
    get,
    listing,
    num,
    ratio,
    table,
)


KITTI_MODELS = ("prior", "untrained", "shipped", "cold_start", "fine_tuned")


def render_selfsup(doc: dict) -> tuple[list[str], list[str]]:
    """Self-supervised against supervised, the masks on the traffic scenario, the KITTI cold start."""
    res = doc.get("results") or {}
    data = []  # the parts that ran (`--parts`)
    if doc.get("train_sequences"):
        train, test = listing(doc.get("train_sequences")), listing(doc.get("test_sequences"))
        data.append(f"training: {train}; test: {test}; {doc.get('epochs', '-')} epochs")
    if doc.get("traffic_train_sequences"):
        train, test = listing(doc.get("traffic_train_sequences")), listing(doc.get("traffic_test_sequences"))
        data.append(f"traffic: training {train}; test {test}")
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
    if rows:
        body += [
            "`traffic` scenario (movers along the epipolar lines; `eq19_only`: the LeoVR paper's eq. 19 test alone; "
            "`oracle_mask`: the true moving mask, a bound):",
            "",
        ]
    body += table(["model", "MAE (m)", "MAE ÷ selfsup_nomask", "train min"], rows)
    rows = []
    for clip, by_input in (res.get("kitti") or {}).items():
        for inp, e in by_input.items():
            minutes = e.get("train_minutes") or {}
            rows.append(
                [clip, inp, f"{e['test_frames'][0]}-{e['test_frames'][1] - 1}" if e.get("test_frames") else "-"]
                + [num(get(e, m, "mae_m")) for m in KITTI_MODELS]
                + [ratio(get(e, m, "mae_m"), get(e, "shipped", "mae_m")) for m in ("cold_start", "fine_tuned")]
                + [
                    ", ".join(
                        ratio(o.get("fine_tuned"), o.get("shipped")) for o in (e.get("other_clips") or {}).values()
                    )
                ]
                + [num(minutes.get("cold_start"), 1), num(minutes.get("fine_tuned"), 1)]
            )
    body += (
        [
            "KITTI raw, self-supervised on each clip's first frames (no ground truth), every model scored on held-out "
            "beams of the last frames (MAE, m): `prior` the classical prior, `untrained` the untrained network, "
            "`cold_start` trained from it, `fine_tuned` the shipped checkpoint trained further (also scored on the "
            "other clips' held-out frames):",
            "",
        ]
        if rows
        else []
    )
    return data, body + table(
        [
            "clip",
            "input",
            "held-out frames",
            *KITTI_MODELS,
            "cold ÷ shipped",
            "fine-tuned ÷ shipped",
            "fine-tuned ÷ shipped, other clips",
            "cold min",
            "fine-tune min",
        ],
        rows,
    )
