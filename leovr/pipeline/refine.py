"""`leovr refine`: generator depth per frame, the visual-LiDAR front end and the sliding-window graph,
frame by frame as a live system would see them; refined depth, poses, metrics and timing written out.

Outputs (all written atomically): `depth/NNNNNN.png` (refined, uint16 metres x 256, the KITTI
depth-completion convention, recorded in `run.json`), `depth_generator/` (the generator alone),
`depth_ipbasic/` (IP-Basic on the same input), `sigma/` (the generator's predicted uncertainty of the refined depth,
one standard deviation, uint16 metres x 256), `poses_kitti.txt`, `poses_tum.txt`, `poses_kiss_icp_kitti.txt` (KISS-ICP
alone on the same input, with
ground-truth poses or `--compare`; `poses_kiss_icp_no_deskew_kitti.txt` beside it when the scans carry point times),
`poses_mono_vo_kitti.txt` (`--compare`), `step_ratio.png` (each trajectory's step lengths over the ground truth's, with
poses), `metrics.json` (when the sequence has ground
truth depth or LiDAR to hold out, and poses; with a cone LiDAR also `nearest_accumulated` / `ipbasic_accumulated`,
the fills of the same frames' returns placed with KISS-ICP's poses), `timing.json`, `landmarks.npy` (world points),
`landmarks_frame.npy` (the frame that last observed each), `landmarks_lidar.npy` (LiDAR-backed or not), and
`progress.json`, the state `--resume`
continues from. A resumed run replays its finished frames through the front end and the window without
rewriting their outputs, so that it ends as the uninterrupted run would: resuming saves the writing and
scoring of finished frames, not their computation.

The run's stages: the generator stage (`refine_prepare`: the frame's input and generator depth, in a second
thread one frame ahead, `lookahead`), the front end and the window update (`RefineRun.step`), the frames
leaving the window (`RefineRun.finish`: depth PNGs, poses, the photometric step of `refine_photometric`), the
whole-recording passes (`refine_passes`) and the outputs (`refine_outputs`); what is scored beside them (held-out
truth, classical fills, pose baselines) is `refine_scoring`'s.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from leovr.config import RefineConfig
from leovr.data.io import atomic_write
from leovr.data.records import Frame
from leovr.data.run_info import run_identity, start_run
from leovr.data.sequence import Sequence
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.lidar.accumulate import ScanHistory
from leovr.pipeline.completion import (
    EvalSample,
    frame_indices,
    generator_checkpoint,
    generator_method,
    warn_empty_input,
)
from leovr.pipeline.frame_writer import FrameWriter
from leovr.pipeline.lookahead import Lookahead
from leovr.pipeline.refine_input import camera_only_config, classical_source, completion_config, road_height
from leovr.pipeline.refine_outputs import FrameScore, input_label, write_outputs
from leovr.pipeline.refine_passes import whole_recording_passes
from leovr.pipeline.refine_photometric import PhotometricStep
from leovr.pipeline.refine_record import RunRecord
from leovr.pipeline.refine_scoring import RunScoring
from leovr.pipeline.refine_prepare import ConeSteps, PreparedFrame, PrepareStage
from leovr.threads import single_threaded_blas, torch_threads

if TYPE_CHECKING:
    from odometry.window_graph import FrameInput, FrameResult


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
    """Refine every selected frame; returns the metrics dictionary (also written to metrics.json).
    `pool` (method -> accumulator) also receives every scored pixel, to pool metrics over sequences;
    `collect` receives each frame's FrameScore (benchmarks that score subsets of frames).
    `score=False` skips everything that reads ground truth (the self-supervised trainer's pose pass)."""
    return RefineRun(seq, cfg, out, resume, progress, score).run(pool, collect)


class RefineRun:
    """One refine run: the front end, the window graph and what the frames leave behind, frame by frame in
    the main thread, with the next frame's generator stage in a second thread (`run`)."""

    def __init__(self, seq: Sequence, cfg: RefineConfig, out: Path, resume: bool, progress: bool, score: bool) -> None:
        from odometry.frontend import FrontEnd
        from odometry.window_graph import WindowGraph

        self.seq, self.cfg, self.out, self.progress = seq, cfg, Path(out), progress
        self.ccfg = ccfg = completion_config(cfg)
        self.indices = indices = frame_indices(len(seq), ccfg)
        names = seq.frame_numbers()
        self.record = RunRecord(self.out, names, indices, resume)  # what is finished; a resume replays it
        self.has_lidar = has_lidar = seq.has_lidar and cfg.input != "none"
        self.generator = generator_method(ccfg) if cfg.depth_source == "generator" else classical_source
        first = seq[indices[0]]
        ocfg = cfg if has_lidar else camera_only_config(cfg)  # the odometry's settings
        self.front = FrontEnd(
            ocfg,
            first.K,
            first.shape,
            first.T_cam_lidar,
            use_lidar=has_lidar,
            camera_height=None if has_lidar else road_height(seq, cfg),
        )
        # the loop pass weighs each step by the window's covariance of it; camera only they come out alike (the road
        # plane sets every step's length), so the marginals that would double the graph's time are left out
        self.graph = WindowGraph(
            ocfg,
            first.K,
            first.shape,
            rng=np.random.default_rng(cfg.seed),
            condition_leaving=has_lidar,
            step_covariances=cfg.loop.enabled and has_lidar,
        )
        # generator depth, its log uncertainty, and the road's scale for it (camera only)
        self.pending: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
        self.empty: list[int] = []  # frames whose LiDAR input has no return inside the image
        self.scoring = RunScoring(seq, cfg, ccfg, self.out, score, first)  # evaluation beside the outputs
        stamps = seq.timestamps()
        checkpoint = generator_checkpoint(ccfg) if cfg.depth_source == "generator" else None
        start_run(
            self.out,
            "refine",
            run_identity("refine", cfg.model_dump(), [seq.path], checkpoint),
            resume,
            input=cfg.input if has_lidar else "none",
            sequence=str(Path(seq.path).resolve()),
            frame_numbers=names,
            **({} if has_lidar else {"camera_height_m": self.front.camera_height}),
        )
        self.frame_dt = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.1
        # a narrow-cone LiDAR's last scans, placed by the graph's poses, join the generator's input (spinning: off)
        self.history = ScanHistory(
            cfg.accumulation.frames if has_lidar else 0, first.T_cam_lidar, cfg.accumulation.check
        )
        self.cone = ConeSteps(has_lidar)  # whether the `auto` cone-LiDAR steps run; the sensor is judged once
        self.photometric = PhotometricStep(seq, cfg, indices, first.K)  # a leaving frame's depth where no return lies
        self.t_end = time.perf_counter()  # the end of the last frame's turn on the run's clock
        self.c_end = time.process_time()  # ... and on the process's CPU clock (every thread, user + system)

    def run(self, pool: dict[str, DepthMetricAccumulator] | None, collect: dict[int, FrameScore] | None) -> dict:
        """Every frame through the window, then the whole-recording passes and the outputs; the metrics."""
        desc = f"refine {input_label(self.cfg.input, self.has_lidar)} (window {self.cfg.window})"
        if self.record.done:
            desc += f", replaying {len(self.record.done)} finished"
        # frame k+1 is read and run through the generator in a second thread while frame k's front end (without
        # earlier scans) and graph run (ONNX Runtime and OpenCV leave the interpreter lock); its inputs are
        # known when it starts (`step`), so the results are those of a sequential run
        # (one core's worth of threads, as in a batch task with one CPU: sequential, in this thread);
        # and its files are read (image decoding leaves the interpreter lock) while this frame's front end runs
        # and each frame's files are compressed and written in a third thread while the next frame runs
        with FrameWriter(threaded=torch_threads() > 1) as self.writer:
            with Lookahead(self.seq.__getitem__, threaded=torch_threads() > 1) as ahead:
                self.stage = PrepareStage(
                    self.seq,
                    self.cfg,
                    self.ccfg,
                    self.indices,
                    self.has_lidar,
                    self.frame_dt,
                    self.generator,
                    self.history,
                    self.cone,
                    ahead,
                )
                self.t_end, self.c_end = time.perf_counter(), time.process_time()
                try:
                    for n, i in enumerate(tqdm(self.indices, desc=desc, unit="frame", disable=not self.progress)):
                        self.step(ahead, n, i)
                finally:
                    self.stage.close()
                    self.front.close()
            left = self.graph.flush()
            if not self.cfg.causal:
                self.finish(left)
                self.record.write(self.writer)
        return self.conclude(pool, collect)

    def step(self, ahead: Lookahead[PreparedFrame, Frame], n: int, i: int) -> None:
        """Frame i (the n-th selected): the front end, the next frame handed to the generator stage, scoring
        and the classical baselines, the window update and the frames leaving it; its times kept."""
        if not ahead.pending:
            ahead.submit(
                self.stage.prepare, i, self.front.sweep_velocity if self.front.prev is not None else None, None
            )
        p = ahead.result()
        following = n + 1 < len(self.indices)
        next_read = None  # camera only: the next frame's read, held before its preparation takes it (`prefetch_motion`)
        if following:
            ahead.read_ahead(self.indices[n + 1])
            if not self.has_lidar and ahead.threaded:
                next_read = ahead.future(self.indices[n + 1])
            self.stage.read_sweep_ahead(self.indices[n + 1])  # beside this frame's front end
        if self.has_lidar and i not in self.record.done and not (p.sample.sparse > 0).any():
            self.empty.append(i)
        self.judge_sensor(p.sample)
        self.history.add(i, p.sample.kept_points)
        # without earlier scans (a spinning LiDAR, or none) the next frame needs nothing of this one: it is
        # prepared beside this frame's front end too, its sweep deskewed with the step before (10 Hz: the speed
        # barely changes in a frame; in turns the images' motion sets the rotation)
        early = following and not self.history.frames
        if early:
            self.submit_next(ahead, n, None)
        t1 = time.perf_counter()
        fi = self.front_end(n, i, p)
        t2 = time.perf_counter()
        if next_read is not None:  # the next frame's camera motion, beside this frame's graph
            self.front.prefetch_motion(self.indices[n + 1], lambda: next_read.result().image)
        if following and not early:
            self.submit_next(ahead, n, fi)
        self.pending[i] = p.depth, p.log_sigma, self.front.depth_scale
        t_base, c_base = time.perf_counter(), time.process_time()  # scoring and baselines: not a frame's time
        self.scoring.frame(i, p.sample, i in self.record.done, self.has_lidar, bool(self.history.frames), self.writer)
        t2b, c2b = time.perf_counter(), time.process_time()
        left = self.graph.add_frame(fi)
        t3 = time.perf_counter()
        # causal: the newest frame's estimate is its output
        self.finish([self.graph.current(i)] if self.cfg.causal else left)
        t4, c4 = time.perf_counter(), time.process_time()
        self.scoring.image(p.sample.frame.image)
        # wall: this frame's share of the run's clock (baselines excluded), the generator overlapping the graph
        wall = 1000.0 * ((t4 - self.t_end) - (t2b - t_base))
        cpu = 1000.0 * ((c4 - self.c_end) - (c2b - c_base))  # every thread's CPU time over the same span
        self.t_end, self.c_end = time.perf_counter(), time.process_time()
        state = self.record.state
        if i not in self.record.done or i not in state.times:  # a resumed frame's record completed by its replay
            state.sources[i] = self.front.sources[-1]
            if self.front.prev is not None and self.front.prev.T_icp is not None:
                state.icp_poses[i] = self.front.prev.T_icp.ravel().tolist()
            state.times[i] = [
                p.generator_ms,
                1000.0 * (t2 - t1),
                1000.0 * (t3 - t2b),
                1000.0 * (t4 - t3),
                wall,
                cpu,
            ]
        self.record.write(self.writer)  # after the frame's record: a causal frame is finished in its own step

    def front_end(self, n: int, i: int, p: PreparedFrame) -> FrameInput:
        """Frame i's initial pose and observations for the graph, with its pair motions and motion-stereo
        corners; its image kept for the photometric step when that runs."""
        sample = p.sample
        prev_i = self.indices[n - 1] if n else None
        # the previous sweep's motion, read from its images: to this frame
        guess = self.stage.sweep_of.pop(prev_i, None)
        # spinning LiDARs only: measured there
        spinning_now = self.cone.spinning is True
        guess = guess if spinning_now else None
        if p.first_scan is not None and self.front.icp is not None:
            self.front.icp.restart(p.first_scan)
        fi = self.front.process(
            i,
            sample.frame.image,
            p.depth,
            p.log_sigma,
            sample.sparse if self.has_lidar else None,
            sample.kept_points,
            self.graph,
            icp_guess=guess,
        )
        fi.pair_motions = p.pairs
        if i not in self.record.done and self.cone.runs(self.cfg.photometric.enabled, sample):
            self.photometric.keep(i, sample)
        return fi

    def judge_sensor(self, sample: EvalSample) -> None:
        """Judged on the first scan with returns: a spinning sensor keeps its own scan, and with
        `depth_factors: auto` the graph leaves the depth to the generator, its window smoothed incrementally."""
        from odometry.initial_pose import is_spinning

        kept = sample.kept_points
        if self.history.sensor_known or kept is None or len(kept) < 100:
            return
        self.history.sensor_known = True
        spinning = is_spinning(kept[:, :3])
        self.cone.spinning = spinning
        if spinning:
            self.history.frames = 0
        self.graph.set_sensor(spinning)

    def submit_next(self, ahead: Lookahead[PreparedFrame, Frame], n: int, fi: FrameInput | None) -> None:
        """The frame after the n-th handed to the generator stage, with the motion to deskew it and the earlier
        scans; `fi`: the n-th frame's front-end output, None when the next frame is prepared before it."""
        earlier = None
        if fi is not None and self.history.frames and self.history.sensor_known:
            # the next frame's pose predicted at constant velocity
            poses = self.latest_poses([s.index for s in self.history.scans]) | {fi.index: fi.T_init}
            earlier = self.history.gather(poses, fi.T_init @ self.front.velocity)
        # until the front end has measured a step: the first two scans' own motion
        first = n == 0 or (fi is None and n == 1)
        velocity = self.stage.start if first and self.stage.start is not None else self.front.sweep_velocity
        ahead.submit(self.stage.prepare, self.indices[n + 1], velocity, earlier)

    def finish(self, results: list[FrameResult]) -> None:
        """The frames leaving the window: refined depth (after the photometric step), both depth PNGs and
        the pose saved; a finished frame of a resumed run only has its replayed pose kept."""
        leaving = {r.index: r.T_world_cam for r in results}  # at the end the whole window leaves at once

        def poses_of(near: list[int]) -> dict[int, np.ndarray]:  # the frames leaving with one: as they leave
            return self.latest_poses(near) | {j: leaving[j] for j in near if j in leaving}

        for r in results:
            gen_depth, log_sigma, scale = self.pending.pop(r.index)
            if r.index in self.record.done:
                self.record.replayed[r.index] = r.T_world_cam
                continue
            refined = np.where(gen_depth > 0, gen_depth * scale * np.exp(r.log_offset), 0.0)
            if r.index in self.photometric:  # where no return lies, the depth its neighbours' images agree with
                refined = self.photometric.correct(r.index, r.T_world_cam, refined, poses_of)
            self.scoring.depth(r.index, gen_depth, refined)
            # the generator's predicted spread (metres), carried to the refined depth (the map's filter)
            sigma = np.exp(log_sigma) * np.where(gen_depth > 0, refined / np.maximum(gen_depth, 1e-6), 0.0)
            maps = {"depth_generator": gen_depth, "depth": refined, "sigma": sigma}
            self.record.finished(r.index, r.T_world_cam, maps, r.step_cov)

    def latest_poses(self, indices_kept: list[int]) -> dict[int, np.ndarray]:
        """The graph's current pose of each frame still in the window, else the pose it left with."""
        out = {}
        for j in indices_kept:
            T = self.graph.poses.get(j)
            T = T if T is not None else self.record.pose(j)
            if T is not None:
                out[j] = T
        return out

    def conclude(self, pool: dict[str, DepthMetricAccumulator] | None, collect: dict[int, FrameScore] | None) -> dict:
        """After the last frame: the single-frame generator's scores, warnings, the whole-recording passes,
        the landmarks, the pose baselines and the accumulated fills, then the outputs and metrics."""
        seq, cfg, indices, state = self.seq, self.cfg, self.indices, self.record.state
        if self.empty:
            warn_empty_input(seq, self.empty)
        self.record.check_replay()
        landmarks, seen_by = self.graph.all_landmarks()
        whole_recording_passes(seq, cfg, self.out, indices, state, landmarks, seen_by)
        self.record.save()
        atomic_write(self.out / "landmarks.npy", lambda tmp: np.save(tmp, landmarks))
        atomic_write(self.out / "landmarks_frame.npy", lambda tmp: np.save(tmp, seen_by))
        lidar_backed = self.graph.lidar_backed()
        atomic_write(self.out / "landmarks_lidar.npy", lambda tmp: np.save(tmp, lidar_backed))
        baselines = self.scoring.conclude(indices, self.has_lidar, self.generator, self.frame_dt, self.progress)
        return write_outputs(
            seq,
            cfg,
            self.ccfg,
            indices,
            state,
            self.out,
            self.has_lidar,
            self.progress,
            pool,
            self.scoring.score,
            self.scoring.scored,
            collect,
            baselines,
            no_returns=len(self.empty) == len(indices),
        )
