"""Which part of the camera-only motion's error matters: swap rotation / direction / length of each
step with the truth's and score (Sim(3) ATE). Development sequences with ground truth only."""
import sys, json
import numpy as np
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.mono_vo import mono_vo_poses

def chain(steps):
    P=[np.eye(4)]
    for T in steps: P.append(P[-1]@T)
    return np.stack(P)

def ang(R): return np.degrees(np.arccos(np.clip((np.trace(R)-1)/2,-1,1)))

cfg = RefineConfig(input="none", camera_height_m=1.65)
gen = generator_method(completion_config(cfg))
for path in sys.argv[1:]:
    seq = open_sequence(path); n=len(seq)
    ref = np.stack([invert_T(seq[0].T_world_cam) @ seq[i].T_world_cam for i in range(n)])
    G = [invert_T(ref[k-1])@ref[k] for k in range(1,n)]
    mm = MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg), ground_sigma_log=cfg.mono_ground_sigma_log)
    E=[]
    for i in range(n):
        f=seq[i]; d, ls = gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
        s=mm.step(f.image,d,ls)
        if s is not None: E.append(s.T_rel)
    np.save(f"/tmp/steps_{path.rstrip('/').split('/')[-1]}.npy", np.stack(E))
    def mix(rot, dirn, length):
        out=[]
        for e,g in zip(E,G):
            T=np.eye(4)
            T[:3,:3]=(g if rot else e)[:3,:3]
            de=e[:3,3]/max(np.linalg.norm(e[:3,3]),1e-9); dg=g[:3,3]/max(np.linalg.norm(g[:3,3]),1e-9)
            L=np.linalg.norm((g if length else e)[:3,3])
            T[:3,3]=(dg if dirn else de)*L
            out.append(T)
        return chain(out)
    row={"seq":path.rstrip('/').split('/')[-1]}
    row["mono_vo"]=round(trajectory_metrics(mono_vo_poses((seq[i].image for i in range(n)), seq[0].K), ref, "sim3")["ate_m"],4)
    for name,(a,b,c) in {"est":(0,0,0),"true_rot":(1,0,0),"true_dir":(0,1,0),"true_len":(0,0,1),"true_rot_dir":(1,1,0),"true_dir_len":(0,1,1),"true_rot_len":(1,0,1)}.items():
        m=trajectory_metrics(mix(a,b,c),ref,"sim3"); row[name]=round(m["ate_m"],4)
    rerr=[ang(e[:3,:3].T@g[:3,:3]) for e,g in zip(E,G)]
    derr=[np.degrees(np.arccos(np.clip(e[:3,3]@g[:3,3]/max(np.linalg.norm(e[:3,3])*np.linalg.norm(g[:3,3]),1e-9),-1,1))) for e,g in zip(E,G)]
    lr=[np.log(max(np.linalg.norm(e[:3,3]),1e-6)/max(np.linalg.norm(g[:3,3]),1e-6)) for e,g in zip(E,G)]
    row["rot_err_deg_med"]=round(float(np.median(rerr)),4); row["dir_err_deg_med"]=round(float(np.median(derr)),3)
    row["len_logerr_sd"]=round(float(np.std(lr)),4); row["len_logerr_mean"]=round(float(np.mean(lr)),4)
    print(json.dumps(row),flush=True)
