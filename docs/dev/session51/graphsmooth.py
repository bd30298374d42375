"""Run `leovr refine --input none` on dev clips, recording MonoMotion's readings; then the graph's poses with
their step lengths replaced by the smoothed (second-order) lengths. Sim(3) ATE."""
import sys, json, os, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parent))
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.refine import run_refine
import odometry.mono_motion as mmod
from odometry.initial_pose import LidarOdometry
from smooth import solve2, chain

REC=[]
orig_step=mmod.MonoMotion.step; orig_fuse=mmod.MonoMotion._fuse
def fuse(self, absolute, log_ratio):
    self._rec=(absolute, log_ratio, self.log_len is None); orig_fuse(self, absolute, log_ratio)
def step(self, image, depth, ls):
    self._rec=None; s=orig_step(self, image, depth, ls)
    if s is not None: REC.append(self._rec)
    return s
mmod.MonoMotion._fuse=fuse; mmod.MonoMotion.step=step

def smoothed_lengths(R, a, q1):
    ok=[k for k,r in enumerate(R) if r is not None]
    links=[kk>0 and ok[kk-1]==k-1 and not R[k][2] for kk,k in enumerate(ok)]
    x=solve2([R[k] for k in ok], a, None, links, q1)
    return dict(zip(ok, np.exp(x)))

def relen(P, L):
    steps=[invert_T(P[k-1])@P[k] for k in range(1,len(P))]
    for k,l in L.items():
        n=np.linalg.norm(steps[k][:3,3])
        if n>1e-9: steps[k][:3,3]*=l/n
    return chain(steps)

extra=dict(s.split("=") for s in os.environ.get("CFG","").split() if s)
cfg = RefineConfig(input="none", camera_height_m=1.65, **{k:float(v) for k,v in extra.items()})
for path in sys.argv[1:]:
    REC.clear()
    seq=open_sequence(path); n=len(seq)
    if seq[0].T_world_cam is not None:
        ref = np.stack([invert_T(seq[0].T_world_cam) @ seq[i].T_world_cam for i in range(n)])
    else:
        icp = LidarOdometry(seq[0].T_cam_lidar); ref=np.stack([icp.register(seq[i].points) for i in range(n)])
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, cfg.model_copy(update={"end": n}), Path(tmp), progress=False, score=False)
        est = read_kitti_poses(Path(tmp) / "poses_kitti.txt")
    name=path.rstrip('/').split('/')[-1]
    np.save(f"/tmp/graph_{name}.npy", est); json.dump([None if r is None else [r[0], r[1], r[2]] for r in REC], open(f"/tmp/rec_{name}.json","w"))
    row={"seq":name,"graph":round(trajectory_metrics(est,ref,"sim3")["ate_m"],4), "nrec":len(REC)}
    for a,q1 in ((0.001,None),(0.001,0.02),(0.0003,0.02)):
        L=smoothed_lengths(REC,a,q1)
        row[f"graph_smooth_a{a}_q{q1}"]=round(trajectory_metrics(relen(est,L),ref,"sim3")["ate_m"],4)
    print(json.dumps(row), flush=True)
