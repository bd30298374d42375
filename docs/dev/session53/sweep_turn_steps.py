"""Session 53 development check (issue 16): the sweep's motion read from the images (`odometry.sweep_motion`) on
steps of a tuning lap, given the true previous step as the last step: whether it overrules that step, and the rotation
error (degrees) of what it returns and of the last step. Tuning laps only.

    .venv/bin/python docs/dev/session53/sweep_turn_steps.py LAP_SEQ [FIRST LAST]   # e.g. lap 3000, steps 27 32
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from leovr.data import open_sequence  # noqa: E402
from leovr.geometry import invert_T, rotation_angle_deg  # noqa: E402
from odometry.features import detect  # noqa: E402
from odometry.sweep_motion import sweep_motion  # noqa: E402


def main() -> None:
    seq = open_sequence(sys.argv[1])
    first, last = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (2, len(seq) - 1)
    for k in range(max(first, 2), last + 1):
        a, b = seq[k - 1], seq[k]
        last_step = invert_T(seq[k - 2].T_world_cam) @ a.T_world_cam
        truth = invert_T(a.T_world_cam) @ b.T_world_cam
        m = sweep_motion(detect(a.image, 2000), detect(b.image, 2000), a.K, last_step, 1.0, 1.5)
        print(k, "images" if m is not last_step else "last step",
              f"error {rotation_angle_deg(m[:3, :3].T @ truth[:3, :3]):.2f}",
              f"last step's error {rotation_angle_deg(last_step[:3, :3].T @ truth[:3, :3]):.2f}")


if __name__ == "__main__":
    main()
