"""Development check of where camera-only poses go wrong, on one simulator sequence with ground truth:
`leovr refine --input none` (camera height 1.65 m unless set), then every 5th frame's rotation error
(degrees about the camera's x = pitch, y = yaw, z = roll), its step length over the true one and its
position error. Development sequences only (the KITTI odometry clip is never read here).

    .venv/bin/python tools/mono_drift.py SEQ [F=V ...]      # F=V: RefineConfig overrides
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from leovr.config import RefineConfig
from leovr.data import open_sequence
from leovr.data.kitti_common import read_kitti_poses
from leovr.geometry import invert_T
from leovr.pipeline.refine import run_refine


def main() -> None:
    path, overrides = sys.argv[1], dict(s.split("=") for s in sys.argv[2:])
    seq = open_sequence(path)
    truth = np.stack([invert_T(seq[0].T_world_cam) @ seq[i].T_world_cam for i in range(len(seq))])
    cfg = RefineConfig(input="none", **{"camera_height_m": 1.65, **{k: float(v) for k, v in overrides.items()}})
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(seq, cfg, Path(tmp), progress=False, score=False)
        est = read_kitti_poses(Path(tmp) / "poses_kitti.txt")
    for i in range(0, len(est), 5):  # `end=N` shortens the run
        err = Rotation.from_matrix(est[i][:3, :3].T @ truth[i][:3, :3]).as_euler("xyz", degrees=True)
        step = 1.0
        if i:
            true_step = np.linalg.norm((invert_T(truth[i - 1]) @ truth[i])[:3, 3])
            step = np.linalg.norm((invert_T(est[i - 1]) @ est[i])[:3, 3]) / max(true_step, 1e-6)
        print(f"frame {i:3d}  rotation error (deg) {np.round(err, 3)}  step ratio {step:.3f}  "
              f"position error (m) {np.round(est[i][:3, 3] - truth[i][:3, 3], 2)}")


if __name__ == "__main__":
    main()
