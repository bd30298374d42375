#!/usr/bin/env python3
"""Print a depth benchmark JSON (`leovr bench ...`) as Markdown tables for docs/benchmarks.md."""

from __future__ import annotations

import json
import sys


def fmt(v, d=3):
    return "-" if v is None else f"{v:.{d}f}"


def main(path: str) -> None:
    doc = json.load(open(path))
    print(f"Command: `{doc['command']}`  ({doc['date_utc']}, {doc['duration_s']} s)\n")
    print("| dataset_input | method | MAE (m) | RMSE (m) | AbsRel | delta1 | p95 (m) | ms/frame | points |")
    print("|---|---|---|---|---|---|---|---|---|")
    for key, methods in doc["results"].items():
        for m, r in methods.items():
            print(f"| {key} | {m} | {fmt(r['mae_m'])} | {fmt(r['rmse_m'])} | {fmt(r['absrel'])} | "
                  f"{fmt(r['delta1'])} | {fmt(r.get('p95_m'))} | {fmt(r.get('ms_per_frame'), 1)} | {r['n']} |")
    bins = list(next(iter(next(iter(doc["results"].values())).values()))["bins"])
    print("\nMAE (m) per distance bin:\n")
    print("| dataset_input | method | " + " | ".join(bins) + " |")
    print("|---|---|" + "---|" * len(bins))
    for key, methods in doc["results"].items():
        for m, r in methods.items():
            print(f"| {key} | {m} | " + " | ".join(fmt(r["bins"][b]["mae_m"]) for b in bins) + " |")


if __name__ == "__main__":
    main(sys.argv[1])
