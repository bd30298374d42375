"""Post hoc: road-height estimator variants (selection of near points by image row instead of triangulated
depth; inverse-height mode and harmonic height), motion alone + smoothed lengths, dev clips."""
import sys, json, os
import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from step_length_dev import chain
import odometry.ground_plane as gp
import odometry.mono_motion as mmod
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.step_length import rescale_steps, smooth_log_lengths

orig=gp.fit_ground
def variant(mode):
    def fit(X, rel_band=0.05, near_share=0.6, max_tilt_deg=10.0, min_inliers=8):
        n0=np.array([0.0,1.0,0.0])
        X=X[np.isfinite(X).all(1)&(X[:,2]>0)]
        if len(X)<min_inliers: return None
        if "row" in mode:
            # nearer by image row: the ray's slope below the axis, y/z, which triangulation noise does not move
            s=X[:,1]/X[:,2]; X=X[s>=np.quantile(s,1-near_share)]
        else:
            X=X[X[:,2]<=np.quantile(X[:,2],near_share)]
        h=X@n0; X,h=X[h>0],h[h>0]
        if len(X)<min_inliers: return None
        if "inv" in mode:
            mode_=1.0/gp.height_mode(1.0/h, rel_band, second_share=10.0)  # no 'lower cluster' rule in inverse space (would flip)
            # keep the lower-surface rule in height space
            m2=gp.height_mode(h, rel_band)
            if m2>mode_*(1+2*rel_band): mode_=m2
        else:
            mode_=gp.height_mode(h, rel_band)
        on=np.abs(h-mode_)<rel_band*mode_
        if on.sum()<min_inliers: return None
        P=X[on]; c=P.mean(0)
        normal=np.linalg.svd(P-c)[2][-1]; normal=normal if normal@n0>0 else -normal
        fitted=bool(normal@n0>=np.cos(np.radians(max_tilt_deg)))
        if not fitted: normal=n0
        height=float(normal@c)
        if "harm" in mode: height=float(1.0/np.median(1.0/np.maximum(P@normal,1e-9)))
        return gp.GroundFit(height,normal,int(on.sum()),fitted) if height>0 else None
    return fit

cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
modes=os.environ.get("MODES","base,row,inv,harm,row_inv_harm").split(",")
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n)
    depth=[]
    for i in range(n):
        f=seq[i]; depth.append(gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None)))
    row={"seq":path.rstrip('/').split('/')[-1]}
    for mode in modes:
        mmod.fit_ground = orig if mode=="base" else variant(mode)
        mm = mmod.MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg) or 1.65, ground_sigma_log=cfg.mono_ground_sigma_log)
        steps=[]; R=[]
        for i in range(n):
            s=mm.step(seq[i].image,*depth[i])
            if s is not None: steps.append(s.T_rel); R.append(s.length_reading)
        P=chain(steps); Ps=rescale_steps(P,np.exp(smooth_log_lengths(R)))
        m=trajectory_metrics(Ps,ref,"sim3")
        # reading bias vs step length: slope of log(reading/ref) against log(ref)
        lr=[]; lg=[]
        for k,r in enumerate(R):
            g=np.linalg.norm((invert_T(ref[k])@ref[k+1])[:3,3])
            if r is not None and r.log_length is not None and g>0.03: lr.append(r.log_length-np.log(g)); lg.append(np.log(g))
        slope=np.polyfit(lg,lr,1)[0] if len(lg)>5 else float('nan')
        row[mode]=f"{m['ate_m']:.4f} s{m['scale']:.3f} b{np.mean(lr):+.3f} sl{slope:+.2f}"
    print(json.dumps(row),flush=True)
