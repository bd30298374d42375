"""Session 57 development check (issue 16, loop laps; tuning / development laps only, kept by
`tools/loop_tuning_dev.py --keep DIR`): where the window pass's step errors lie. Per lap: the rms of each
camera-frame component of the step's translation error on the straights and in the turns (true turn over 2 degrees
a frame), then each turning step's relative length error.

    .venv/bin/python docs/dev/session57/step_errors.py DIR
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
sys.path.insert(0, str(Path(__file__).resolve().parents[3] / 'tools'))
import numpy as np, gtsam
from leovr.geometry import invert_T
from pose_graph_dev import lap_data
keep=Path(sys.argv[1])
for tag in ['mid40_3000','mid40_3001','mid40_3002','mid40_3003','vlp16_3000','vlp16_3001']:
    before, ref, loops = lap_data(keep, tag)
    E=[];Y=[];L=[]
    for k in range(1,len(before)):
        de=invert_T(before[k-1])@before[k]; dr=invert_T(ref[k-1])@ref[k]
        E.append(de[:3,3]-dr[:3,3]); L.append(np.linalg.norm(dr[:3,3]))
        Y.append(np.degrees(np.linalg.norm(gtsam.Rot3(dr[:3,:3]).ypr())))
    E=np.array(E);Y=np.array(Y);L=np.array(L)
    turn=Y>2
    f=lambda m: " ".join(f"{np.sqrt(np.mean(E[m,i]**2)):.3f}" for i in range(3))
    # cumulative forward error on straights
    print(tag, "n",len(E),"turn",turn.sum(), "rms xyz straight",f(~turn),"turn",f(turn),
          "sum z err straight %.2f turn %.2f"%(E[~turn,2].sum(),E[turn,2].sum()), "rel len err straight %.3f"%(E[~turn,2].sum()/L[~turn].sum()))
print()
for tag in ['mid40_3000','mid40_3001','mid40_3002','mid40_3003']:
    before, ref, loops = lap_data(keep, tag)
    rows=[]
    for k in range(1,len(before)):
        de=invert_T(before[k-1])@before[k]; dr=invert_T(ref[k-1])@ref[k]
        y=np.degrees(np.linalg.norm(gtsam.Rot3(dr[:3,:3]).ypr()))
        rows.append((k,y,np.linalg.norm(dr[:3,3]),np.linalg.norm(de[:3,3]), de[:3,3]-dr[:3,3]))
    turn=[r for r in rows if r[1]>2]
    le=np.array([r[3]-r[2] for r in turn]); L=np.array([r[2] for r in turn])
    print(tag,"turn steps: median rel len err %.3f mean %.3f; per-step rel:"%(np.median(le/L),np.mean(le/L)), " ".join(f"{r[0]}:{(r[3]-r[2])/r[2]:+.2f}" for r in turn))
