"""Offline: re-solve the camera-only step lengths as a smoother (least squares over the whole chain of
the filter's own readings) instead of the forward Kalman filter; Sim(3) ATE against truth."""
import sys, json, os
import numpy as np
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.initial_pose import LidarOdometry

def chain(steps):
    P=[np.eye(4)]
    for T in steps: P.append(P[-1]@T)
    return np.stack(P)

def solve2(recs, a, r, links, q1=None):
    """abs readings + track changes (sigma r) + second differences (sigma a) [+ first differences q1]."""
    n=len(recs); A=[]; rhs=[]; w=[]
    for k,(ab,lr,_) in enumerate(recs):
        if ab is not None:
            e=np.zeros(n); e[k]=1; A.append(e); rhs.append(ab[0]); w.append(1/ab[1])
        if k>0 and links[k]:
            e=np.zeros(n); e[k]=1; e[k-1]=-1
            if lr is not None and r: A.append(e); rhs.append(lr); w.append(1/r)
            if q1: A.append(e.copy()); rhs.append(0.0); w.append(1/q1)
            if k>1 and links[k-1]:
                e=np.zeros(n); e[k]=1; e[k-1]=-2; e[k-2]=1; A.append(e); rhs.append(0.0); w.append(1/a)
    A=np.array(A)*np.array(w)[:,None]; b=np.array(rhs)*np.array(w)
    return np.linalg.lstsq(A,b,rcond=None)[0]

def solve(recs, q, r, links):
    """recs: per step (absolute or None, log_ratio or None, filtered log length). LS over the chain."""
    n=len(recs); rows=[]; rhs=[]; w=[]
    A=[]
    for k,(ab,lr,_) in enumerate(recs):
        if ab is not None:
            e=np.zeros(n); e[k]=1; A.append(e); rhs.append(ab[0]); w.append(1/ab[1])
        if k>0 and links[k]:
            e=np.zeros(n); e[k]=1; e[k-1]=-1
            A.append(e); rhs.append(0.0); w.append(1/q)
            if lr is not None:
                A.append(e.copy()); rhs.append(lr); w.append(1/r)
    A=np.array(A)*np.array(w)[:,None]; b=np.array(rhs)*np.array(w)
    return np.linalg.lstsq(A,b,rcond=None)[0]

def main():
    cfg = RefineConfig(input="none", camera_height_m=1.65)
    gen = generator_method(completion_config(cfg))
    for path in sys.argv[1:]:
        seq = open_sequence(path); n=len(seq)
        if seq[0].T_world_cam is not None:
            ref = np.stack([invert_T(seq[0].T_world_cam) @ seq[i].T_world_cam for i in range(n)])
        else:
            icp = LidarOdometry(seq[0].T_cam_lidar); ref=np.stack([icp.register(seq[i].points) for i in range(n)])
        G = [invert_T(ref[k-1])@ref[k] for k in range(1,n)]
        mm = MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                        camera_height=road_height(seq, cfg), ground_sigma_log=cfg.mono_ground_sigma_log)
        cur={}
        orig=mm._fuse
        def fuse(absolute, log_ratio):
            cur["f"]=(absolute, log_ratio)
            cur["restart"]=mm.log_len is None
            orig(absolute, log_ratio)
        mm._fuse=fuse
        E=[]; R=[]
        for i in range(n):
            f=seq[i]; d, ls = gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
            cur.clear()
            s=mm.step(f.image,d,ls)
            if s is not None:
                E.append(s.T_rel); R.append((*cur["f"], cur["restart"]) if "f" in cur else None)
        row={"seq":path.rstrip('/').split('/')[-1], "est":round(trajectory_metrics(chain(E),ref,"sim3")["ate_m"],4)}
        ok=[k for k,r_ in enumerate(R) if r_ is not None]
        row["fused"]=len(ok); row["breaks"]=sum(1 for kk,k in enumerate(ok) if kk>0 and (ok[kk-1]!=k-1 or R[k][2]))
        q,r=mm.speed_sigma_log, mm.track_sigma_log
        links=[kk>0 and ok[kk-1]==k-1 and not R[k][2] for kk,k in enumerate(ok)]
        variants={"smooth":lambda: solve([R[k] for k in ok], q, r, links)}
        for a_ in (0.0003,0.001,0.003):
            for r_ in (None,0.1):
                variants[f"acc{a_}_r{r_}"]=(lambda a_=a_,r_=r_: solve2([R[k] for k in ok], a_, r_, links))
        for a_,q_ in ((0.001,0.01),(0.001,0.02),(0.0003,0.02)):
            variants[f"acc{a_}_q{q_}"]=(lambda a_=a_,q_=q_: solve2([R[k] for k in ok], a_, None, links, q_))
        for name,fn in variants.items():
            x=fn()
            S=[T.copy() for T in E]
            for kk,k in enumerate(ok):
                L=np.linalg.norm(E[k][:3,3]); 
                if L>0: S[k][:3,3]*=np.exp(x[kk])/L
            row[name]=round(trajectory_metrics(chain(S),ref,"sim3")["ate_m"],4)
        T2=[]
        for e,g in zip(E,G):
            T=e.copy(); L=np.linalg.norm(e[:3,3]); 
            if L>0: T[:3,3]*=np.linalg.norm(g[:3,3])/L
            T2.append(T)
        row["true_len"]=round(trajectory_metrics(chain(T2),ref,"sim3")["ate_m"],4)
        print(json.dumps(row),flush=True)
        if os.environ.get("TABLE"):
            x=solve([R[k] for k in ok], q, r, [kk>0 and ok[kk-1]==k-1 and not R[k][2] for kk,k in enumerate(ok)])
            xs=dict(zip(ok,x))
            for k,(e,g) in enumerate(zip(E,G)):
                rr_=R[k]
                ab="" if rr_ is None or rr_[0] is None else f"{np.exp(rr_[0][0]):.3f}+-{rr_[0][1]:.2f}"
                lr="" if rr_ is None or rr_[1] is None else f"{rr_[1]:+.3f}"
                print(f"{k:3d} ref {np.linalg.norm(g[:3,3]):.3f} filt {np.linalg.norm(e[:3,3]):.3f} smooth {np.exp(xs[k]) if k in xs else float('nan'):.3f} abs {ab:14s} dlog {lr:7s} restart {rr_[2] if rr_ else ''}")

if __name__=='__main__':
    main()
