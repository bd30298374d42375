"""Session 58 development check (issue 16, loop laps; *tuning / development* laps only, kept by
`tools/loop_tuning_dev.py --keep DIR`): what ATE ratio (with loops / without) can a lap reach when the
odometry's errors are white noise, however small?

For each kept lap it takes the true trajectory and the run's accepted loop pairs, draws odometry whose
every step is the true step times Exp(xi), xi ~ N(0, diag(sigma^2)) independent per step, closes the same
loop pairs measured nearly exactly, and solves the Gaussian pose graph with the *true* sigmas (the MAP
estimate: no weighting can do better on average). SE(3) ATE as `leovr bench loop`. Noise shapes:
- measured: each tangent axis's rms of the lap's own window-pass step errors (straights and turns apart);
- rotation only / translation only / forward translation only (the same rms on those axes);
- the measured shape scaled by 0.1 (the linear regime: the ratio should not move).

    .venv/bin/python docs/dev/session58/loop_ratio_montecarlo.py runs/s54/laps [--draws 40]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from leovr.eval.trajectory import trajectory_metrics  # noqa: E402
from leovr.geometry import invert_T  # noqa: E402
from odometry.loop.pose_graph import build_pose_graph, solve_pose_graph  # noqa: E402
from pose_graph_dev import lap_data  # noqa: E402

LOOP_SIG = np.r_[np.full(3, 0.002), np.full(3, 0.01)]
FLOOR = np.r_[np.full(3, 1e-4), np.full(3, 1e-3)]  # the other axes' sigma in the one-part shapes (well conditioned)


def steps(P: np.ndarray) -> np.ndarray:
    """The F-1 relative steps (camera k-1 to k) of F camera-to-world poses."""
    return invert_T(P[:-1]) @ P[1:]


def chain(first: np.ndarray, d: list[np.ndarray]) -> np.ndarray:
    out = [first]
    for s in d:
        out.append(out[-1] @ s)
    return np.stack(out)


def exp(xi: np.ndarray) -> np.ndarray:
    return gtsam.Pose3.Expmap(xi).matrix()


def one_draw(ref, loops, sig_steps, rng):
    """sig_steps: (F-1) x 6 per-step sigmas. Returns (ATE without loops, ATE with loops)."""
    d_ref = steps(ref)
    d_est = [d @ exp(rng.normal(0, s)) for d, s in zip(d_ref, sig_steps)]
    odo = chain(ref[0], d_est)
    meas = [(i, j, invert_T(ref[j]) @ ref[i] @ exp(rng.normal(0, LOOP_SIG))) for i, j, _ in loops]
    noise = [None] + [gtsam.noiseModel.Diagonal.Sigmas(np.maximum(s, 1e-7)) for s in sig_steps]
    g, v = build_pose_graph(odo, meas, lambda k: noise[k], gtsam.noiseModel.Diagonal.Sigmas(LOOP_SIG))
    fixed = solve_pose_graph(g, v, len(odo))
    ate = lambda P: trajectory_metrics(P, ref, "se3")["ate_m"]  # noqa: E731
    return ate(odo), ate(fixed)


def measured_sigmas(before, ref):
    """Per-step sigmas from the lap's own step errors: per-axis rms, turns (> 2 deg a frame) and straights apart."""
    err, turn = [], []
    for de, dr in zip(steps(before), steps(ref)):
        err.append(gtsam.Pose3.Logmap(gtsam.Pose3(invert_T(dr) @ de)))
        turn.append(np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(dr[:3, :3])))) > 2.0)
    err, turn = np.asarray(err), np.asarray(turn)
    rms = lambda m: np.sqrt(np.mean(err[m] ** 2, 0)) if m.any() else np.sqrt(np.mean(err ** 2, 0))  # noqa: E731
    s_turn, s_str = rms(turn), rms(~turn)
    return np.where(turn[:, None], s_turn, s_str), s_turn, s_str


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("keep", type=Path)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--only", nargs="*", default=None, help="noise shapes to run (names as printed; default all)")
    a = ap.parse_args()
    print("| lap | noise shape | mean ATE no loops (m) | mean ATE loops (m) | ratio of means | median ratio | share of draws <= 0.4 |")
    print("|---|---|---|---|---|---|---|")
    for run in sorted(a.keep.glob("run_*")):
        if not (run / "loops.json").exists():
            continue
        tag = run.name[4:]
        before, ref, loops = lap_data(a.keep, tag)
        if not loops:
            continue
        meas, s_turn, s_str = measured_sigmas(before, ref)
        rot_rms = np.sqrt(np.mean(meas[:, :3] ** 2, 0))
        tr_rms = np.sqrt(np.mean(meas[:, 3:] ** 2, 0))
        n = len(meas)
        shapes = {
            "measured (turns / straights apart)": meas,
            "measured, turn steps' translation as on the straights": np.where(meas[:, :1] > 0, np.c_[meas[:, :3], np.tile(s_str[3:], (n, 1))], meas),
            "measured, translation x 0.5": meas * np.r_[np.ones(3), np.full(3, 0.5)],
            "measured, translation x 0.25": meas * np.r_[np.ones(3), np.full(3, 0.25)],
            "measured x 0.1": 0.1 * meas,
            "measured, uniform over the lap": np.tile(np.sqrt(np.mean(meas ** 2, 0)), (n, 1)),
            "rotation only": np.tile(np.r_[rot_rms, FLOOR[3:]], (n, 1)),
            "translation only": np.tile(np.r_[FLOOR[:3], tr_rms], (n, 1)),
            "forward translation only": np.tile(np.r_[FLOOR[:3], FLOOR[3:5], np.linalg.norm(tr_rms)], (n, 1)),
        }
        for name, sig in shapes.items():
            if a.only and name not in a.only:
                continue
            rng = np.random.default_rng(0)
            res = np.array([one_draw(ref, loops, sig, rng) for _ in range(a.draws)])
            r = res[:, 1] / res[:, 0]
            print(f"| {tag} | {name} | {res[:, 0].mean():.3f} | {res[:, 1].mean():.3f} | {res[:, 1].mean() / res[:, 0].mean():.2f} "
                  f"| {np.median(r):.2f} | {np.mean(r <= 0.4):.2f} |", flush=True)
        print(f"<!-- {tag}: turn sigmas {np.round(s_turn, 4).tolist()} straight {np.round(s_str, 4).tolist()} loops {len(loops)} -->", flush=True)


if __name__ == "__main__":
    main()
