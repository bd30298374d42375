"""Session 54 development check (issue 16): the pair motions offered to the window graph for given frames of a
*tuning* lap (or validation drive), each against the truth and the front end's initial pose, and whether the pair
gate kept it (`WindowGraph._pair_agrees`).

    .venv/bin/python docs/dev/session54/pair_trace.py SEQ END FRAME [FRAME ...]
"""
import json
import sys
import tempfile
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import numpy as np
import odometry.window_graph as wg
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T, rotation_angle_deg as ang
from leovr.pipeline.refine import run_refine
seq=open_sequence(sys.argv[1]); frames=[int(x) for x in sys.argv[3:]]; end=int(sys.argv[2])
gt={i: seq[i].T_world_cam for i in range(len(seq))}
agrees=wg.WindowGraph._pair_agrees
def logged(self,f,j,T,second):
    ok=agrees(self,f,j,T,second)
    if f.index in frames:
        true=invert_T(gt[j])@gt[f.index]; init=invert_T(self.poses[j])@f.T_init
        print(json.dumps({"frame":f.index,"j":j,"kept":ok,"pair_t":np.round(T[:3,3],2).tolist(),"true_t":np.round(true[:3,3],2).tolist(),"init_t":np.round(init[:3,3],2).tolist(),"pair_rot_err":round(ang(T[:3,:3].T@true[:3,:3]),2)}),flush=True)
    return ok
wg.WindowGraph._pair_agrees=logged
with tempfile.TemporaryDirectory() as tmp:
    run_refine(seq, RefineConfig(end=end), Path(tmp)/'run', progress=False)
