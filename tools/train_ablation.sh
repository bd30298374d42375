#!/usr/bin/env bash
# Train the three ablation variants one after another (configs/ablation/*.yaml -> runs/ablation_<name>),
# resuming any that was interrupted, then evaluate them with tools/ablate_generator.py.
set -euo pipefail
cd "$(dirname "$0")/.."
for v in full no_attention interp; do
  out=runs/ablation_$v
  if [ -f "$out/checkpoint_last.pt" ]; then resume=--resume; else resume=; fi
  if [ "$(wc -l < "$out/log.jsonl" 2>/dev/null || echo 0)" -lt 2 ]; then
    .venv/bin/leovr train --mode supervised --config configs/ablation/$v.yaml --out "$out" $resume
  fi
done
.venv/bin/python tools/ablate_generator.py --out docs/results/ablation.json
