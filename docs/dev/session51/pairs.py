"""Post hoc on dev clips: camera-only pose graph with pair motions (k-2, k-3 -> k) as direction constraints."""
import sys, json, os
import numpy as np, cv2, gtsam
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from step_length_dev import chain
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.mono_vo import gray, corners, follow, relative_motion
from odometry.step_length import rescale_steps, smooth_log_lengths

def cov(R_ij, d_i, L, along, across, rot):
    d=R_ij.T@d_i; d/=np.linalg.norm(d)
    St=along**2*np.outer(d,d)+across**2*(np.eye(3)-np.outer(d,d))
    C=np.zeros((6,6)); C[:3,:3]=np.eye(3)*rot**2; C[3:,3:]=St
    return gtsam.noiseModel.Gaussian.Covariance(C)

cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
JS=[int(x) for x in os.environ.get("JS","2,3").split(",")]
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n); K=seq[0].K
    mm = MonoMotion(K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg) or 1.65, ground_sigma_log=cfg.mono_ground_sigma_log)
    steps=[]; R=[]; grays=[]
    for i in range(n):
        f=seq[i]; d,ls=gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
        s=mm.step(f.image,d,ls); grays.append(gray(f.image))
        if s is not None: steps.append(s.T_rel); R.append(s.length_reading)
    P=rescale_steps(chain(steps),np.exp(smooth_log_lengths(R)))
    base=trajectory_metrics(P,ref,"sim3")["ate_m"]
    pairs={}
    for k in range(n):
        for j in JS:
            if k-j<0: continue
            p0=corners(grays[k-j]); p1,ok=follow(grays[k-j],grays[k],p0)
            T,inl=relative_motion(p0[ok],p1[ok],K,method=cv2.USAC_ACCURATE)
            if T is None: continue
            chord=invert_T(P[k-j])@P[k]
            if T[:3,3]@chord[:3,3]<0: continue
            pairs[(k-j,k)]=T
    out={"seq":path.rstrip('/').split('/')[-1],"smooth":round(base,4),"pairs":len(pairs)}
    for name,(st_across,pr_across,rot) in {"g_steps_only":(0.005,None,0.0005),"g_pairs":(0.005,0.003,0.0005),"g_pairs_loose_steps":(0.01,0.003,0.0005),"g_pairs_tight":(0.005,0.0015,0.0005)}.items():
        g=gtsam.NonlinearFactorGraph(); v=gtsam.Values()
        g.add(gtsam.PriorFactorPose3(0,gtsam.Pose3(P[0]),gtsam.noiseModel.Isotropic.Sigma(6,1e-6)))
        for k in range(n):
            v.insert(k,gtsam.Pose3(P[k]))
            if k:
                S=invert_T(P[k-1])@P[k]; L=max(np.linalg.norm(S[:3,3]),1e-3)
                g.add(gtsam.BetweenFactorPose3(k-1,k,gtsam.Pose3(S),cov(S[:3,:3],S[:3,3],L,0.01*L+0.002,st_across*L+0.001,rot)))
        if pr_across:
            for (a,b),T in pairs.items():
                C=invert_T(P[a])@P[b]; L=np.linalg.norm(C[:3,3])
                if L<0.05: continue
                M=np.eye(4); M[:3,:3]=T[:3,:3]; M[:3,3]=T[:3,3]/np.linalg.norm(T[:3,3])*L
                g.add(gtsam.BetweenFactorPose3(a,b,gtsam.Pose3(M),gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),cov(M[:3,:3],M[:3,3],L,0.5*L,pr_across*L+0.001,rot))))
        res=gtsam.LevenbergMarquardtOptimizer(g,v).optimize()
        Q=np.stack([res.atPose3(k).matrix() for k in range(n)])
        out[name]=round(trajectory_metrics(Q,ref,"sim3")["ate_m"],4)
    print(json.dumps(out),flush=True)
