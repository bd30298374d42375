"""Session 53 development check (issue 16): KISS-ICP's adaptive threshold and the rotation sigma of the registration
covariance the graph receives, per frame, on a tuning lap's first frames, with `icp_guess` as given. Run it once per
setting and compare the lines (one JSON line per registration; the first two are `first_step`'s own KISS-ICP).
The figures in docs/benchmarks.md ("Session 53", threshold 3-10x, covariance 1-5.5x smaller when the threshold
learnt from the predictions) came from this script on 63dad9a, where it did.

    .venv/bin/python docs/dev/session53/threshold_covariance.py LAP_SEQ {constant_velocity|images} [FRAMES]
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import odometry.initial_pose as ip  # noqa: E402
from leovr.config import RefineConfig  # noqa: E402
from leovr.data import open_sequence  # noqa: E402
from leovr.pipeline.refine import run_refine  # noqa: E402


def main() -> None:
    seq_dir, guess = sys.argv[1], sys.argv[2]
    end = int(sys.argv[3]) if len(sys.argv) > 3 else 36
    register = ip.LidarOdometry.register

    def logged(self, points, times=None, guess=None):
        T = register(self, points, times, guess)
        cov = self.covariance  # computed once and cached, as the front end reads it
        print(json.dumps({"predicted": guess is not None, "threshold_m": round(self.icp.adaptive_threshold.get_threshold(), 3),
                          "cov_rot_deg": None if cov is None else round(float(np.degrees(np.sqrt(np.trace(cov[:3, :3])))), 3)}),
              flush=True)
        return T

    ip.LidarOdometry.register = logged
    with tempfile.TemporaryDirectory() as tmp:
        run_refine(open_sequence(seq_dir), RefineConfig(input="full", end=end, icp_guess=guess), Path(tmp) / "run", progress=False)


if __name__ == "__main__":
    main()
