"""`leovr refine`: generator depth per frame, the visual-LiDAR front end and the sliding-window graph,
frame by frame as a live system would see them; refined depth, poses and timing written out, then scored.

Outputs (all written atomically): `depth/NNNNNN.png` (refined, uint16 metres x 256, the KITTI depth-completion
convention, recorded in `run.json`), `depth_generator/` (the generator alone), `sigma/` (the generator's predicted
uncertainty of the refined depth, one standard deviation, uint16 metres x 256), `poses_kitti.txt`, `poses_tum.txt`,
`timing.json`, `landmarks.npy` (world points), `landmarks_frame.npy` (the frame that last observed each),
`landmarks_lidar.npy` (LiDAR-backed or not), and `progress.json`, the state `--resume` continues from. A resumed run
replays its finished frames through the front end and the window without rewriting their outputs, so that it ends
as the uninterrupted run would: resuming saves the writing of finished frames, not their computation.

Then the scoring pass: `depth_ipbasic/` (IP-Basic on the same input), `poses_kiss_icp_kitti.txt` (KISS-ICP alone on
the same input, with ground-truth poses or `--compare`; `poses_kiss_icp_no_deskew_kitti.txt` beside it when the scans
carry point times), `poses_mono_vo_kitti.txt` (`--compare`), `step_ratio.png` (each trajectory's step lengths over
the ground truth's, with poses) and `metrics.json` (depth when the sequence has ground truth depth or LiDAR to hold
out, trajectories with poses; with a cone LiDAR also `nearest_accumulated` / `ipbasic_accumulated`, the fills of the
same frames' returns placed with KISS-ICP's poses).

The run's stages: what it fixes before the first frame (`refine_setup`), the generator stage (`refine_prepare`:
the frame's input, deskewed over its sweep by `refine_sweep`, and generator depth, with a cone LiDAR's corner tracks
of `refine_tracks`; in a second thread one frame ahead, `lookahead`), the front end and the window update
(`RefineRun.step`), the frames leaving the window (`refine_leaving`: depth PNGs, poses, the photometric step of
`refine_photometric`), the whole-recording passes (`refine_passes`) and the outputs (`refine_outputs`). The
evaluation is a pass over the written outputs once the frames are done (`refine_scoring`: held-out truth, classical
fills, pose baselines; `refine_metrics`: metrics.json); the frame loop keeps none of its state.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from leovr.config import RefineConfig
from leovr.data.io import atomic_write
from leovr.data.records import Frame
from leovr.data.sequence import Sequence
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.lidar.accumulate import ScanHistory
from leovr.pipeline.completion import EvalSample, warn_empty_input
from leovr.pipeline.frame_clock import FrameClock
from leovr.pipeline.frame_writer import FrameWriter
from leovr.pipeline.lookahead import Lookahead
from leovr.pipeline.refine_leaving import LeavingFrames
from leovr.pipeline.refine_metrics import FrameScore, write_metrics
from leovr.pipeline.refine_outputs import input_label, write_outputs
from leovr.pipeline.refine_passes import whole_recording_passes
from leovr.pipeline.refine_prepare import ConeSteps, PreparedFrame, PrepareStage
from leovr.pipeline.refine_record import RunRecord
from leovr.pipeline.refine_scoring import score_run
from leovr.pipeline.refine_setup import RunSetup
from leovr.threads import single_threaded_blas, torch_threads

if TYPE_CHECKING:
    from odometry.window_graph import FrameInput, WindowGraph


@single_threaded_blas
def run_refine(
    seq: Sequence,
    cfg: RefineConfig,
    out: Path,
    resume: bool = False,
    progress: bool = True,
    pool: dict[str, DepthMetricAccumulator] | None = None,
    score: bool = True,
    collect: dict[int, FrameScore] | None = None,
) -> dict:
    """Refine every selected frame, then score what the run wrote; returns the metrics dictionary (also written to
    metrics.json). `pool` (method -> accumulator) also receives every scored pixel, to pool metrics over sequences;
    `collect` receives each frame's FrameScore (benchmarks that score subsets of frames).
    `score=False` skips the scoring pass but for `--compare`'s textbook VO: no held-out truth, no classical fills
    (`depth_ipbasic/`), no KISS-ICP unless compared (the self-supervised trainer's pose pass)."""
    s = RunSetup.of(seq, cfg, out, progress)
    run = RefineRun(s, resume)
    run.run()
    timing = conclude(s, run.record, run.graph)
    # the evaluation: a pass over what the run wrote
    scores = score_run(s, run.record.state, several=bool(run.history.frames), score=score)
    if collect is not None:
        collect.update(scores.frames)
    no_returns = len(run.record.empty) == len(s.indices)
    return write_metrics(
        seq, cfg, s.ccfg, s.indices, run.record.state, s.out, s.has_lidar, timing, scores, pool, no_returns
    )


class RefineRun:
    """One refine run: the front end, the window graph and what the frames leave behind, frame by frame in
    the main thread, with the next frame's generator stage in a second thread (`run`)."""

    def __init__(self, setup: RunSetup, resume: bool) -> None:
        self.setup = s = setup
        # what is finished; a resume replays it
        self.record = RunRecord(s.out, s.seq.frame_numbers(), s.indices, resume)
        self.front, self.graph = s.odometry()
        s.start(resume, self.front.camera_height)
        # a narrow-cone LiDAR's last scans, placed by the graph's poses, join the generator's input (spinning: off)
        frames = s.cfg.accumulation.frames if s.has_lidar else 0
        self.history = ScanHistory(frames, s.first.T_cam_lidar, s.cfg.accumulation.check)
        self.cone = ConeSteps(s.has_lidar)  # whether the `auto` cone-LiDAR steps run; the sensor is judged once
        self.leaving = LeavingFrames(s, self.record, self.graph)
        self.clock = FrameClock()

    def run(self) -> None:
        """Every frame through the window; the frames still in it leave at the end."""
        s = self.setup
        desc = f"refine {input_label(s.cfg.input, s.has_lidar)} (window {s.cfg.window})"
        if self.record.done:
            desc += f", replaying {len(self.record.done)} finished"
        # frame k+1 is read and run through the generator in other threads while frame k's front end and graph run,
        # and frame k's files are written in a third (ONNX Runtime, OpenCV and image codecs leave the interpreter
        # lock); its inputs are known when it starts (`step`): the results are a sequential run's, as with one core
        threaded = torch_threads() > 1
        with FrameWriter(threaded) as self.writer, Lookahead(s.seq.__getitem__, threaded) as ahead:
            self.stage = PrepareStage(s, self.history, self.cone, ahead)
            self.clock.restart()
            try:
                for n, i in enumerate(tqdm(s.indices, desc=desc, unit="frame", disable=not s.progress)):
                    self.step(ahead, n, i)
            finally:
                self.stage.close()
                self.front.close()
            left = self.graph.flush()
            if not s.cfg.causal:
                self.leaving.finish(left)
                self.record.write(self.writer)

    def step(self, ahead: Lookahead[PreparedFrame, Frame], n: int, i: int) -> None:
        """Frame i (the n-th selected): the front end, the next frame handed to the generator stage, the window
        update and the frames leaving it; its times kept."""
        s, front = self.setup, self.front
        if not ahead.pending:
            ahead.submit(self.stage.prepare, i, front.sweep_velocity if front.prev is not None else None, None)
        p = ahead.result()
        following = n + 1 < len(s.indices)
        next_read = None  # camera only: the next frame's read, held before its preparation takes it (`prefetch_motion`)
        if following:
            ahead.read_ahead(s.indices[n + 1])
            if not s.has_lidar and ahead.threaded:
                next_read = ahead.future(s.indices[n + 1])
            self.stage.read_sweep_ahead(s.indices[n + 1])  # beside this frame's front end
        if s.has_lidar and i not in self.record.done and not (p.sample.sparse > 0).any():
            self.record.empty.append(i)
        judge_sensor(p.sample, self.history, self.cone, self.graph)
        self.history.add(i, p.sample.kept_points)
        # without earlier scans (a spinning LiDAR, or none) the next frame needs nothing of this one: it is
        # prepared beside this frame's front end too, its sweep deskewed with the step before (10 Hz: the speed
        # barely changes in a frame; in turns the images' motion sets the rotation)
        early = following and not self.history.frames
        if early:
            self.submit_next(ahead, n, None)
        times = [p.generator_ms]
        with self.clock.stage(times):
            fi = self.front_end(n, i, p)
        if next_read is not None:  # the next frame's camera motion, beside this frame's graph
            front.prefetch_motion(s.indices[n + 1], lambda: next_read.result().image)
        if following and not early:
            self.submit_next(ahead, n, fi)
        self.leaving.hold(i, p.depth, p.log_sigma, front.depth_scale)
        with self.clock.stage(times):
            left = self.graph.add_frame(fi)
        with self.clock.stage(times):  # causal: the newest frame's estimate is its output
            self.leaving.finish([self.graph.current(i)] if s.cfg.causal else left)
        # wall: this frame's share of the run's clock, the generator overlapping the graph;
        # cpu: every thread's CPU time over the same span
        T_icp = front.prev.T_icp if front.prev is not None else None
        deskewed = p.motion if p.sample.frame.point_times is not None else None
        self.record.frame_done(i, front.sources[-1], T_icp, [*times, *self.clock.turn()], deskewed)
        self.record.write(self.writer)  # after the frame's record: a causal frame is finished in its own step

    def front_end(self, n: int, i: int, p: PreparedFrame) -> FrameInput:
        """Frame i's initial pose and observations for the graph, with its pair motions and motion-stereo
        corners; its image kept for the photometric step when that runs."""
        s, sample = self.setup, p.sample
        prev_i = s.indices[n - 1] if n else None
        # the previous sweep's motion, read from its images: KISS-ICP's prediction of this frame (every LiDAR: left
        # to its constant velocity, a cone's registration at speed loses the first turn and stays lost)
        guess = self.stage.sweep.motion_of.pop(prev_i, None)
        if p.first_scan is not None and self.front.icp is not None:
            self.front.icp.restart(p.first_scan)
        sparse = sample.sparse if s.has_lidar else None
        fi = self.front.process(
            i,
            sample.frame.image,
            p.depth,
            p.log_sigma,
            sparse,
            sample.kept_points,
            self.graph,
            icp_guess=guess,
            images_step=p.pairs.get(prev_i),
        )
        fi.pair_motions = p.pairs
        if i not in self.record.done and self.cone.runs(s.cfg.photometric.enabled, sample):
            self.leaving.photometric.keep(i, sample)
        return fi

    def submit_next(self, ahead: Lookahead[PreparedFrame, Frame], n: int, fi: FrameInput | None) -> None:
        """The frame after the n-th handed to the generator stage, with the motion to deskew it and the earlier
        scans; `fi`: the n-th frame's front-end output, None when the next frame is prepared before it."""
        earlier = None
        if fi is not None and self.history.frames and self.history.sensor_known:
            # the next frame's pose predicted at constant velocity
            poses = self.leaving.latest_poses([s.index for s in self.history.scans]) | {fi.index: fi.T_init}
            earlier = self.history.gather(poses, fi.T_init @ self.front.velocity)
        # until the front end has measured a step: the first two scans' own motion
        first, start = n == 0 or (fi is None and n == 1), self.stage.sweep.start
        velocity = start if first and start is not None else self.front.sweep_velocity
        ahead.submit(self.stage.prepare, self.setup.indices[n + 1], velocity, earlier)


def judge_sensor(sample: EvalSample, history: ScanHistory, cone: ConeSteps, graph: WindowGraph) -> None:
    """Judged on the first scan with returns: a spinning sensor keeps its own scan, and with
    `depth_factors: auto` the graph leaves the depth to the generator, its window smoothed incrementally."""
    from odometry.initial_pose import MIN_JUDGED_RETURNS, is_spinning

    kept = sample.kept_points
    if history.sensor_known or kept is None or len(kept) < MIN_JUDGED_RETURNS:
        return
    history.sensor_known = True
    spinning = is_spinning(kept[:, :3])
    cone.spinning = spinning
    if spinning:
        history.frames = 0
    graph.set_sensor(spinning)


def conclude(setup: RunSetup, record: RunRecord, graph: WindowGraph) -> dict:
    """After the last frame: warnings, the whole-recording passes, the landmarks, the poses and timing.json;
    returns the timing record."""
    s, state = setup, record.state
    if record.empty:
        warn_empty_input(s.seq, record.empty)
    record.check_replay()
    landmarks, seen_by = graph.all_landmarks()
    whole_recording_passes(s.seq, s.cfg, s.out, s.indices, state, landmarks, seen_by)
    record.save()
    atomic_write(s.out / "landmarks.npy", lambda tmp: np.save(tmp, landmarks))
    atomic_write(s.out / "landmarks_frame.npy", lambda tmp: np.save(tmp, seen_by))
    atomic_write(s.out / "landmarks_lidar.npy", lambda tmp: np.save(tmp, graph.lidar_backed()))
    return write_outputs(s.seq, s.indices, state, s.out)
