#!/usr/bin/env python3
"""Thread settings of the overlapped refine run (the generator's thread beside the graph), on the 200-frame
development drive of session 55 (seed 2100, `graph_steps.py`'s docstring): VARIANT `base`, `ort1` (ONNX Runtime
with one intra-op thread), `cv1` (OpenCV with one thread), `ort1cv1`; FRAMES: the first N frames.

    .venv/bin/python docs/dev/session55/threads_dev.py VARIANT FRAMES [DRIVE]
"""
import json, sys, tempfile, time
from pathlib import Path
import numpy as np, torch, cv2
import leovr.depth.runtime as rt
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.pipeline.refine import run_refine
variant = sys.argv[1]
class P:
    def __getattr__(self, k): return getattr(torch, k)
    def get_num_threads(self): return 1
if 'ort1' in variant:
    rt.torch = P()
if 'cv1' in variant:
    cv2.setNumThreads(1)
seq = open_sequence(Path(sys.argv[3] if len(sys.argv) > 3 else 'runs/s55/dev2100'))
cfg = RefineConfig(end=int(sys.argv[2]) if len(sys.argv) > 2 else None)
with tempfile.TemporaryDirectory() as d:
    t0 = time.perf_counter()
    m = run_refine(seq, cfg, Path(d) / 'run', progress=False)
    wall = time.perf_counter() - t0
st = m['timing']['stats']
print(variant, json.dumps({k: round(v['median'], 1) for k, v in st.items()}), 'graph p95/med %.3f' % (st['graph_ms']['p95'] / st['graph_ms']['median']),
      'wall_s %.1f' % wall, 'MAE %.4f ATE %.4f' % (m['depth']['refined']['mae_m'], m['trajectory']['leovr']['ate_m']), flush=True)
