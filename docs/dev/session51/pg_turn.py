"""Tuning laps: pose graph with rotation sigma growing with each step's own measured rotation."""
import sys
from pathlib import Path
import numpy as np, gtsam
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from pose_graph_dev import lap_data
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T

def ang(R): return np.arccos(np.clip((np.trace(R)-1)/2,-1,1))

def solve(poses, loops, s0, c, tm=0.05, tper=0.0, loop_sigma=(0.02,0.1)):
    g,v=gtsam.NonlinearFactorGraph(),gtsam.Values()
    lc=gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3,loop_sigma[0]),np.full(3,loop_sigma[1])]))
    g.add(gtsam.PriorFactorPose3(0,gtsam.Pose3(poses[0]),gtsam.noiseModel.Isotropic.Sigma(6,1e-6)))
    for k,T in enumerate(poses):
        v.insert(k,gtsam.Pose3(T))
        if k:
            S=invert_T(poses[k-1])@T; a=ang(S[:3,:3]); L=np.linalg.norm(S[:3,3])
            sig=np.r_[np.full(3,s0+c*a),np.full(3,tm+tper*L)]
            g.add(gtsam.BetweenFactorPose3(k-1,k,gtsam.Pose3(S),gtsam.noiseModel.Diagonal.Sigmas(sig)))
    for i,j,T in loops: g.add(gtsam.BetweenFactorPose3(j,i,gtsam.Pose3(T),lc))
    r=gtsam.LevenbergMarquardtOptimizer(g,v).optimize()
    return np.stack([r.atPose3(k).matrix() for k in range(len(poses))])

keep=Path(sys.argv[1])
for run in sorted(keep.glob("run_*")):
    tag=run.name[4:]; before,ref,loops=lap_data(keep,tag)
    a0=trajectory_metrics(before,ref,"se3")["ate_m"]
    out=[f"{tag} no-loop {a0:.3f}"]
    for s0,c in ((0.01,0),(0.002,0),(0.001,0.1),(0.001,0.3),(0.002,0.3),(0.0005,0.5)):
        P=solve(before,loops,s0,c); a=trajectory_metrics(P,ref,"se3")["ate_m"]; out.append(f"s{s0}/c{c}: {a:.3f} ({a/a0:.2f})")
    print("  ".join(out))
