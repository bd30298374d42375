"""The evaluation of a refine run: a pass over what the run wrote, once its frames are done. Each frame's input is
rebuilt as the run deskewed it (`Progress.deskew`) and its held-out truth built; the run's depth PNGs are scored
there beside the classical fills of that input (IP-Basic written to `depth_ipbasic/`) and, where earlier scans
joined the generator's input, the generator on the frame's own scan; the pose baselines (the textbook monocular VO
with `--compare`, KISS-ICP with and without its deskew, beside the frames' scores where it is needed); then a cone
LiDAR's accumulated fills. The refine loop itself keeps no evaluation state."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from leovr.data.io import write_depth_png
from leovr.data.kitti_common import write_kitti_poses
from leovr.data.records import Frame
from leovr.data.run_info import png_name, read_run_depth
from leovr.depth.fills import complete_depth
from leovr.pipeline.accumulated_baseline import accumulated_fills
from leovr.pipeline.completion import EvalSample, with_truth
from leovr.pipeline.kiss_baseline import kiss_icp_trajectories
from leovr.pipeline.refine_metrics import FrameScore, RunScores
from leovr.pipeline.refine_outputs import Progress
from leovr.pipeline.refine_setup import RunSetup
from leovr.threads import Worker, torch_threads

RUN_DEPTH = {"generator": "depth_generator", "refined": "depth"}  # method -> the run's PNG folder


def score_run(setup: RunSetup, state: Progress, several: bool, score: bool) -> RunScores:
    """Every selected frame scored (none with `score=False`), the textbook VO run on the images (`--compare`), then
    the pose baselines and, where `several` (earlier scans joined the generator's input), the accumulated fills."""
    from odometry.mono_vo import MonoVO

    s, scores = setup, RunScores()
    textbook = MonoVO(s.first.K) if s.cfg.compare else None  # the `mono_vo` baseline on the same images
    frames = s.indices if score or textbook is not None else []

    def read(i: int) -> tuple[Frame, EvalSample | None, np.ndarray | None]:
        """Frame i and, when scored, its input as the run deskewed it, with its held-out truth, and with `several`
        the generator's depth on that input alone (the network releases the interpreter: it runs beside the
        previous frame's score)."""
        frame = s.seq[i]
        if not score:
            return frame, None, None
        sample = with_truth(s.sample(frame, state.deskew_motion(i)), s.ccfg)
        return frame, sample, s.generator(sample)[0] if several and sample.gt_kind != "none" else None

    names = s.seq.frame_numbers()  # the run's PNG names
    threaded = torch_threads() > 1
    # KISS-ICP reads the frames on its own, beside the frames' scores, where it is known to be needed (compared, or
    # poses to score it against); the next frame read beside this one's score
    beside, reader, pending = Worker("kiss", threaded), Worker("score", threaded), {}
    icp_runs = beside.submit(kiss_runs, s, score and s.first.T_world_cam is not None, s.progress and not threaded)
    try:
        for n, i in enumerate(tqdm(frames, desc="score", unit="frame", disable=not s.progress or not frames)):
            for j in frames[n : n + 2]:
                if j not in pending:
                    pending[j] = reader.submit(read, j)
            frame, sample, single = pending.pop(i).result()
            if textbook is not None:
                textbook.add(frame.image)
            if sample is not None:
                scores.gt_poses.append(frame.T_world_cam)
                fs = score_frame(s, i, sample, single, names)
                if fs is not None:
                    scores.frames[i] = fs
        runs = icp_runs.result()
    finally:
        reader.close(cancel=True)
        beside.close()
    if textbook is not None:
        scores.baselines["mono_vo"] = np.stack(textbook.poses), "sim3"
        write_kitti_poses(s.out / "poses_mono_vo_kitti.txt", scores.baselines["mono_vo"][0])
    accumulated = several and bool(scores.frames)
    if runs is None and accumulated:  # the accumulated fills place the scans with KISS-ICP's poses
        runs = kiss_runs(s, True, s.progress)
    icp = kiss_baselines(s, scores, runs)
    if accumulated and icp is not None:  # the fills given the same frames: the yardstick for a cone's several scans
        accumulated_fills(
            s.seq,
            s.indices,
            s.ccfg,
            icp,
            scores.frames,
            list(scores.frames),
            s.cfg.accumulation.frames,
            causal=s.cfg.causal,
            frame_dt=s.frame_dt,
            progress=s.progress,
        )
    return scores


def score_frame(
    s: RunSetup, i: int, sample: EvalSample, single: np.ndarray | None, names: list[int]
) -> FrameScore | None:
    """Frame i's score on its input as the run built it (`sample`, with its truth), its IP-Basic fill written: the
    run's depth PNGs (named by `names`, the sequence's frame numbers), the fills of that input and `single`, the
    generator's depth on it alone (where earlier scans joined the run's generator input); None without truth."""
    frame = sample.frame
    ipbasic = complete_depth(sample.sparse, "ipbasic") if s.has_lidar else None
    if ipbasic is not None:
        write_depth_png(s.out / "depth_ipbasic" / png_name(names, i), ipbasic)
    fs = FrameScore.of(sample)
    if fs is None:
        return None
    if ipbasic is not None:
        fs.add("ipbasic", ipbasic)
        fs.add("nearest", complete_depth(sample.sparse, "nearest"))
    for method, folder in RUN_DEPTH.items():
        fs.add(method, read_run_depth(s.out, folder, i, frame.shape))
    if single is not None:  # the same-run yardstick for what the earlier scans and the graph add
        fs.add("generator_frame", single)
    return fs


def kiss_runs(s: RunSetup, needed: bool, progress: bool) -> dict[bool, np.ndarray] | None:
    """KISS-ICP with and without its deskew (without where scans carry point times: the other way to run it) on
    the run's input, with a LiDAR when compared or `needed` (deskew setting -> camera poses; None: not run);
    `progress`: its bar (not beside the frames' scores)."""
    if not s.has_lidar or not (s.cfg.compare or needed):
        return None
    deskews = (True, False) if s.first.point_times is not None else (True,)
    return kiss_icp_trajectories(s.seq, s.indices, s.ccfg, deskews, progress)


def kiss_baselines(s: RunSetup, scores: RunScores, runs: dict[bool, np.ndarray] | None) -> np.ndarray | None:
    """KISS-ICP's runs (`kiss_runs`) added to the baselines and their pose files written; returns the deskewed
    run's poses (None when it did not run)."""
    if runs is None:
        return None
    for deskew, name in ((True, "kiss_icp"), (False, "kiss_icp_no_deskew")):
        if deskew in runs:
            scores.baselines[name] = runs[deskew], "se3"
            write_kitti_poses(s.out / f"poses_{name}_kitti.txt", runs[deskew])
    return runs[True]
