import sys, json
import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from step_length_dev import chain, motion_steps
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.eval.trajectory import trajectory_metrics
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
from odometry.step_length import rescale_steps, smooth_log_lengths, LengthReading

def variant(R, mode):
    x=smooth_log_lengths(R)
    for _ in range(3):
        res=[]; idx=[]
        for k,r in enumerate(R):
            if r is not None and r.log_length is not None and np.isfinite(x[k]):
                res.append((r.log_length-x[k])/r.sigma_log); idx.append(k)
        res=np.array(res)
        if mode=="scale":
            s=1.4826*np.median(np.abs(res)); R2=[None if r is None else LengthReading(r.log_length, r.sigma_log*s, r.restart) for r in R]
        else:  # huber at 1.345 sigma
            R2=list(R)
            for k,e in zip(idx,res):
                if abs(e)>1.345: r=R[k]; R2[k]=LengthReading(r.log_length, r.sigma_log*np.sqrt(abs(e)/1.345), r.restart)
        x=smooth_log_lengths(R2)
    return x, (s if mode=="scale" else None)

cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n)
    steps, R = motion_steps(seq, cfg, gen)
    P=chain(steps)
    row={"seq":path.rstrip('/').split('/')[-1],"shipped":round(trajectory_metrics(rescale_steps(P,np.exp(smooth_log_lengths(R))),ref,"sim3")["ate_m"],4)}
    for mode in ("scale","huber"):
        x,sc=variant(R,mode); row[mode]=round(trajectory_metrics(rescale_steps(P,np.exp(x)),ref,"sim3")["ate_m"],4)
        if sc: row["noise_scale"]=round(float(sc),3)
    print(json.dumps(row),flush=True)
