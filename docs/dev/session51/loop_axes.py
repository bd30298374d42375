"""Where the loop laps' error lies after loop closure: vertical vs horizontal, heading vs tilt (tuning laps)."""
import sys, json
from pathlib import Path
import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from pose_graph_dev import lap_data
from leovr.eval.trajectory import trajectory_metrics
from odometry.loop.pose_graph import optimise_pose_graph

def umeyama_se3(A,B):
    ma,mb=A.mean(0),B.mean(0); U,_,Vt=np.linalg.svd((B-mb).T@(A-ma)); S=np.eye(3); S[2,2]=np.sign(np.linalg.det(U@Vt)); R=U@S@Vt
    return R, mb-R@ma

keep=Path(sys.argv[1])
for run in sorted(keep.glob("run_*")):
    tag=run.name[4:]
    before,ref,loops=lap_data(keep,tag)
    state=json.loads((run/"progress.json").read_text())
    idx=sorted(int(k) for k in state["poses"]); after=np.stack([np.array(state["poses"][str(i)]).reshape(4,4) for i in idx])
    for name,P in (("before",before),("after",after)):
        R,t=umeyama_se3(P[:,:3,3],ref[:,:3,3]); X=P[:,:3,3]@R.T+t; e=X-ref[:,:3,3]
        # gravity: the first camera's y axis is down
        vert=np.sqrt(np.mean(e[:,1]**2)); hor=np.sqrt(np.mean(e[:,0]**2+e[:,2]**2))
        # tilt: angle between estimated and true camera y axes after alignment; heading: yaw diff about y
        Ry=[(R@P[k,:3,:3])[:,1] for k in range(len(P))]; tilt=[np.degrees(np.arccos(np.clip(a@ref[k,:3,1],-1,1))) for k,a in enumerate(Ry)]
        print(f"{tag:12s} {name:6s} ATE {np.sqrt(np.mean(np.sum(e**2,1))):.3f}  horizontal {hor:.3f} vertical {vert:.3f}  tilt median {np.median(tilt):.2f} max {np.max(tilt):.2f} deg")
