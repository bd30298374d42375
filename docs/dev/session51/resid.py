import sys, json
import numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3] / 'tools'))
from mono_dev import reference
from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.geometry import invert_T
from leovr.pipeline.completion import EvalSample, generator_method
from leovr.pipeline.refine import completion_config, road_height
from odometry.mono_motion import MonoMotion
cfg = RefineConfig(input="none"); gen = generator_method(completion_config(cfg))
for path in sys.argv[1:]:
    seq=open_sequence(path); n=len(seq); ref,_=reference(seq,n)
    mm = MonoMotion(seq[0].K, cfg.mono_depth_sigma_log, cfg.mono_track_sigma_log, cfg.mono_speed_sigma_log,
                    camera_height=road_height(seq, cfg) or 1.65, ground_sigma_log=cfg.mono_ground_sigma_log)
    res=[]; sig=[]; filt=[]
    for i in range(n):
        f=seq[i]; d,ls=gen(EvalSample(f, np.zeros(f.shape, np.float32), None, "none", None))
        s=mm.step(f.image,d,ls)
        if s is None: continue
        k=i; g=np.linalg.norm((invert_T(ref[k-1])@ref[k])[:3,3])
        r=s.length_reading
        if r is not None and r.log_length is not None and g>0.02:
            res.append(r.log_length-np.log(g)); sig.append(r.sigma_log); filt.append(np.log(max(np.linalg.norm(s.T_rel[:3,3]),1e-6))-np.log(g))
    res=np.array(res); res0=res-res.mean(); filt=np.array(filt)
    ac=[float(np.corrcoef(res0[:-l],res0[l:])[0,1]) for l in (1,2,3,5,10)]
    print(path.rstrip('/').split('/')[-1], "n",len(res),"sd",round(res.std(),3),"median sigma",round(float(np.median(sig)),3),"autocorr lag1,2,3,5,10",np.round(ac,2), "filter err sd", round(filt.std(),3))
