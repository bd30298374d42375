"""Post hoc on dev clips: directions of travel from the rotation (non-holonomic: the chord lies at half the
step's rotation from the vehicle's forward axis, estimated over the clip), with smoothed lengths."""
import sys, json
import numpy as np
from scipy.spatial.transform import Rotation as Rot
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from step_length_dev import chain, motion_steps
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.step_length import rescale_steps, smooth_log_lengths

def half(R):
    return Rot.from_rotvec(0.5*Rot.from_matrix(R).as_rotvec()).as_matrix()

def nh_steps(steps, moving_min=0.05, blend=1.0):
    d=[]; 
    for T in steps:
        L=np.linalg.norm(T[:3,3])
        if L>moving_min: d.append(half(T[:3,:3]).T@(T[:3,3]/L))
    f=np.median(np.array(d),axis=0); f/=np.linalg.norm(f)
    out=[]
    for T in steps:
        L=np.linalg.norm(T[:3,3]); S=T.copy()
        if L>1e-9:
            dn=half(T[:3,:3])@f; de=T[:3,3]/L
            v=blend*dn+(1-blend)*de; S[:3,3]=L*v/np.linalg.norm(v)
        out.append(S)
    return out, f

cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n)
    steps, R = motion_steps(seq, cfg, gen)
    Ls=np.exp(smooth_log_lengths(R))
    P=chain(steps); Ps=rescale_steps(P,Ls)
    sm=[invert_T(Ps[k-1])@Ps[k] for k in range(1,len(Ps))]
    nh,f=nh_steps(sm); nh5,_=nh_steps(sm,blend=0.5)
    G=[invert_T(ref[k-1])@ref[k] for k in range(1,n)]
    gd=[half(g[:3,:3]).T@(g[:3,3]/np.linalg.norm(g[:3,3])) for g in G if np.linalg.norm(g[:3,3])>0.05]
    fe=np.median(np.array(gd),axis=0) if gd else np.zeros(3)
    # direction errors per step, deg
    def derr(S): return np.median([np.degrees(np.arccos(np.clip(s[:3,3]@g[:3,3]/max(np.linalg.norm(s[:3,3])*np.linalg.norm(g[:3,3]),1e-12),-1,1))) for s,g in zip(S,G) if np.linalg.norm(g[:3,3])>0.05])
    row={"seq":path.rstrip('/').split('/')[-1],"smooth":round(trajectory_metrics(Ps,ref,"sim3")["ate_m"],4),
         "smooth_nh":round(trajectory_metrics(chain(nh),ref,"sim3")["ate_m"],4),
         "smooth_nh_half":round(trajectory_metrics(chain(nh5),ref,"sim3")["ate_m"],4),
         "dir_err_smooth":round(derr(sm),3),"dir_err_nh":round(derr(nh),3),"f_est":np.round(f,4).tolist(),"f_ref":np.round(fe,4).tolist()}
    print(json.dumps(row),flush=True)
