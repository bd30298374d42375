"""Post-hoc: log-length smoother with the step-length change prior in metres per frame (a vehicle's
acceleration), iterated; dev clips."""
import sys, json
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from step_length_dev import chain, motion_steps
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.step_length import rescale_steps, smooth_log_lengths

def solve(chainr, sig_m, acc_log, iters=4, L0=None):
    m=len(chainr)
    w=np.array([0.0 if r.log_length is None else 1/r.sigma_log for r in chainr])
    y=np.array([0.0 if r.log_length is None else r.log_length for r in chainr])
    x = np.log(L0) if L0 is not None else smooth_log_lengths(chainr, 0.01, 0.1)
    for _ in range(iters):
        rows=[sp.diags(w)]; rhs=[w*y]
        if m>1:
            L=np.exp(0.5*(x[1:]+x[:-1])); wq=L/sig_m
            rows.append(sp.diags(wq)@sp.diags([-np.ones(m-1),np.ones(m-1)],[0,1],shape=(m-1,m))); rhs.append(np.zeros(m-1))
        if m>2 and acc_log:
            rows.append(sp.diags([np.ones(m-2),-2*np.ones(m-2),np.ones(m-2)],[0,1,2],shape=(m-2,m))/acc_log); rhs.append(np.zeros(m-2))
        A=sp.vstack(rows).tocsc(); x=np.atleast_1d(spsolve((A.T@A).tocsc(), A.T@np.concatenate(rhs)))
    return x

def smooth(readings, sig_m, acc):
    n=len(readings); out=np.full(n,np.nan); k=0
    while k<n:
        if readings[k] is None: k+=1; continue
        e=k+1
        while e<n and readings[e] is not None and not readings[e].restart: e+=1
        out[k:e]=solve(readings[k:e], sig_m, acc); k=e
    return out

cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
grid=[(0.002,None),(0.005,None),(0.01,None),(0.005,0.001),(0.01,0.001),(0.003,None)]
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n)
    steps, R = motion_steps(seq, cfg, gen)
    P=chain(steps)
    row={"seq":path.rstrip('/').split('/')[-1],"filtered":round(trajectory_metrics(P,ref,"sim3")["ate_m"],4),
         "shipped":round(trajectory_metrics(rescale_steps(P,np.exp(smooth_log_lengths(R,0.001,0.02))),ref,"sim3")["ate_m"],4),
         "rts_log0.005":round(trajectory_metrics(rescale_steps(P,np.exp(smooth_log_lengths(R,1.0,0.005))),ref,"sim3")["ate_m"],4)}
    for sm,acc in grid:
        row[f"m{sm}_a{acc}"]=round(trajectory_metrics(rescale_steps(P,np.exp(smooth(R,sm,acc))),ref,"sim3")["ate_m"],4)
    print(json.dumps(row),flush=True)
