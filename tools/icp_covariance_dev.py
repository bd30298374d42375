#!/usr/bin/env python3
"""Calibrate `icp_cov_inflation` on development data only (simulator validation sequences, seeds
2000-2002): the chi-square of KISS-ICP's frame-to-frame motion error against the registration
covariance (`odometry.initial_pose.registration_covariance`), per sequence; the inflation that brings
the median to 5.35 (the median of a 6-dof chi-square) is printed.

    .venv/bin/python tools/icp_covariance_dev.py SEQ [SEQ ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from leovr.data import open_sequence
from leovr.geometry import invert_T
from odometry.initial_pose import LidarOdometry

CHI2_6_MEDIAN = 5.348


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sequences", nargs="+")
    a = ap.parse_args()
    every = []
    for path in a.sequences:
        seq = open_sequence(path)
        icp = LidarOdometry(seq[0].T_cam_lidar)
        prev, prev_gt, chi = None, None, []
        for i in range(len(seq)):
            f = seq[i]
            T = icp.register(f.points)
            if prev is not None and icp.covariance is not None:
                d = invert_T(invert_T(prev_gt) @ f.T_world_cam) @ (invert_T(prev) @ T)
                e = np.r_[cv2.Rodrigues(d[:3, :3])[0].ravel(), d[:3, 3]]
                chi.append(float(e @ np.linalg.solve(icp.covariance, e)))
            prev, prev_gt = T, f.T_world_cam
        every += chi
        print(json.dumps({"sequence": Path(path).name, "frames": len(chi), "median_chi2": round(float(np.median(chi)), 1),
                          "inflation": round(float(np.median(chi)) / CHI2_6_MEDIAN, 1)}), flush=True)
    print(json.dumps({"all_median_chi2": round(float(np.median(every)), 1),
                      "inflation": round(float(np.median(every)) / CHI2_6_MEDIAN, 1)}))


if __name__ == "__main__":
    main()
