"""`leovr refine`: generator depth per frame, the visual-LiDAR front end and the sliding-window graph,
frame by frame as a live system would see them; refined depth, poses, metrics and timing written out.

Outputs (all written atomically): `depth/NNNNNN.png` (refined, uint16 metres x 256, the KITTI
depth-completion convention, recorded in `run.json`), `depth_generator/` (the generator alone),
`depth_ipbasic/` (IP-Basic on the same input), `poses_kitti.txt`, `poses_tum.txt`, `poses_kiss_icp_kitti.txt` (KISS-ICP alone on the same input, with
ground-truth poses or `--compare`; `poses_kiss_icp_no_deskew_kitti.txt` beside it when the scans carry point times), `poses_mono_vo_kitti.txt` (`--compare`), `metrics.json` (when the sequence has ground
truth depth or LiDAR to hold out, and poses; with a cone LiDAR also `nearest_accumulated` / `ipbasic_accumulated`,
the fills of the same frames' returns placed with KISS-ICP's poses), `timing.json`, `landmarks.npy` (world points), `landmarks_frame.npy` (the frame that last observed each), `landmarks_lidar.npy` (LiDAR-backed or not), and `progress.json`, the state `--resume`
continues from. A resumed run replays its finished frames through the front end and the window without
rewriting their outputs, so that it ends as the uninterrupted run would: resuming saves the writing and
scoring of finished frames, not their computation.
"""

from __future__ import annotations

import json
import time
import warnings
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from leovr.config import CompleteConfig, FrameSelection, RefineConfig
from leovr.data.io import atomic_write, format_max_depth, write_depth_png, write_text
from leovr.data.kitti_common import write_kitti_poses
from leovr.data.native import write_tum_poses
from leovr.data.records import Frame
from leovr.data.run_info import png_name, read_run_depth, run_identity, start_run
from leovr.data.sequence import Sequence
from leovr.depth.classical import complete_depth
from leovr.errors import DataError
from leovr.eval.depth_metrics import DepthMetricAccumulator
from leovr.eval.heldout import parallax_filter
from leovr.eval.trajectory import trajectory_metrics
from leovr.geometry import invert_T
from leovr.lidar.accumulate import ScanHistory, with_history
from leovr.lidar.deskew import deskew_frame
from leovr.lidar.projection import sparse_depth
from leovr.pipeline.completion import (
    EvalSample,
    frame_indices,
    generator_checkpoint,
    generator_method,
    ground_truth_note,
    prepare_sample,
    warn_empty_input,
    with_truth,
)
from leovr.pipeline.accumulated_baseline import ACCUMULATED, accumulated_fills
from leovr.pipeline.kiss_baseline import kiss_icp_trajectory
from leovr.threads import single_threaded_blas


def completion_config(cfg: RefineConfig) -> CompleteConfig:
    """The generator with the run's input and scoring settings, as `complete` would run it."""
    shared = set(FrameSelection.model_fields)
    settings = cfg.model_dump(include=shared)
    if settings["input"] == "none":  # camera only: the generator gets no LiDAR (frame_sample), the scan is truth
        settings["input"] = "full"
    return CompleteConfig(method="generator", **settings)


def classical_source(sample: EvalSample) -> tuple[np.ndarray, np.ndarray]:
    """IP-Basic depth with its holes (above the scan) filled from the nearest completed pixel, and a
    flat 20 % relative sigma: the graph's depth input when no trained network may be used (the
    self-supervised cold start)."""
    from scipy.ndimage import distance_transform_edt

    depth = complete_depth(sample.sparse, "ipbasic")
    hole = depth <= 0
    if hole.all():
        raise DataError(f"frame {sample.frame.index}", "no LiDAR return in the image: nothing to complete")
    if hole.any():
        _, (iv, iu) = distance_transform_edt(hole, return_indices=True)
        depth = depth[iv, iu]
    return depth, np.log(0.2 * depth)


def stereo_image(seq: Sequence, j: int) -> np.ndarray | None:
    """Frame j's image for motion stereo, None when it cannot be read (the frame's own turn reports it)."""
    from leovr.data.io import read_image

    try:
        path = seq.image_path(j)
        return read_image(path, gray=True) if path is not None else seq[j].image
    except DataError:
        return None


def torch_threads() -> int:
    import torch

    return torch.get_num_threads()


def frame_sample(seq: Sequence, i: int, ccfg: CompleteConfig, motion_cam: np.ndarray | None = None,
                 frame_dt: float = 0.1, camera_only: bool = False, truth: bool = True,
                 frame: Frame | None = None) -> EvalSample:
    """The frame with its cheap LiDAR input (deskewed when a motion is given) and ground truth; without
    LiDAR (or `camera_only`, `--input none`) an empty input, and the whole scan, if any, held out.
    `truth=False`: a held-out truth is left for `with_truth` (prepare_sample). `frame`: seq[i], read already."""
    f = deskew_frame(seq[i] if frame is None else frame, motion_cam, frame_dt)
    has_points = f.points is not None and len(f.points) > 0
    if has_points and not camera_only:
        return prepare_sample(f, ccfg, truth)
    empty = np.zeros(f.shape, np.float32)
    if f.depth is not None:
        return EvalSample(f, empty, f.depth, "dense", None)
    if has_points:
        every = sparse_depth(f.points, f.K, f.T_cam_lidar, f.shape)
        return EvalSample(f, empty, parallax_filter(every, every, ccfg.parallax_window, ccfg.parallax_rel), "heldout", None)
    return EvalSample(f, empty, empty, "none", None)


# per frame, in timing.json as means: the generator (prior included, and the sweep's motion read from the
# images when it is), the front end, the graph update, and the
# writing of the frames that left the window (depth PNGs, progress.json); the baselines beside them are not timed.
# `total_ms` is their sum (the cost of a sequential run); `wall_ms` the frame's time on the run's clock, shorter
# because the generator of the next frame runs while the graph updates
TIMED = ("generator_ms", "frontend_ms", "graph_ms", "output_ms")
WALL = "wall_ms"
SCORED = ("nearest", "ipbasic", *ACCUMULATED, "generator", "generator_frame", "refined")  # depth methods in metrics.json, same pixels
# generator: as it ran in the graph (with earlier scans for a cone LiDAR); generator_frame: on the frame's own scan alone;
# nearest / ipbasic_accumulated: the fills of the same frames' returns placed with KISS-ICP's poses (cone LiDAR only)
PNG_FOLDER = {"ipbasic": "depth_ipbasic", "generator": "depth_generator", "refined": "depth"}


@dataclass
class FrameScore:
    """A frame's ground-truth pixels and each method's depth there, taken from the arrays the run
    produced (the PNGs hold the same maps to 1/256 m)."""

    kind: str
    pick: tuple[np.ndarray, np.ndarray]
    gt: np.ndarray
    pred: dict[str, np.ndarray] = field(default_factory=dict)
    # the frame's own cheap input (rows, cols, depth) when earlier scans joined the generator's: the
    # single-frame generator (`generator_frame`) is scored from it after the run, not timed
    own_input: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @classmethod
    def of(cls, sample: EvalSample) -> "FrameScore | None":
        if sample.gt_kind == "none":
            return None
        pick = np.nonzero(np.isfinite(sample.gt) & (sample.gt > 0))
        return cls(sample.gt_kind, pick, sample.gt[pick])

    def add(self, method: str, depth: np.ndarray) -> None:
        """Scored as its depth PNG holds it, saturated at the format's largest depth (a far cell's correction
        can carry pixels past 256 m; scored unsaturated, they counted kilometres that no file held)."""
        self.pred[method] = np.minimum(depth[self.pick], format_max_depth())


@dataclass
class Progress:
    """What has been finished: poses (camera to world) and the front end's choices, per frame index."""

    poses: dict[int, list[float]] = field(default_factory=dict)
    icp_poses: dict[int, list[float]] = field(default_factory=dict)
    sources: dict[int, str] = field(default_factory=dict)
    poses_no_loop: dict[int, list[float]] = field(default_factory=dict)  # before loop closure, when it ran
    poses_window: dict[int, list[float]] = field(default_factory=dict)  # the window pass's, when a later pass moved them
    times: dict[int, list[float]] = field(default_factory=dict)  # frame -> ms per stage of TIMED

    @classmethod
    def load(cls, path: Path) -> "Progress":
        try:
            d = json.loads(path.read_text())
            d.setdefault("poses_no_loop", {})  # only runs with loop closure have it
            d.setdefault("poses_window", {})  # only runs whose poses a whole-recording pass moved
            keyed = {name: {int(k): v for k, v in d[name].items()}
                     for name in ("poses", "icp_poses", "sources", "poses_no_loop", "poses_window", "times")}
            return cls(**keyed)
        except (OSError, ValueError, KeyError) as exc:
            raise DataError(path, f"cannot resume from this progress file: {exc}") from exc

    def save(self, path: Path) -> None:
        write_text(path, json.dumps(self.__dict__) + "\n")

    def stacked(self, name: str, indices: list[int]) -> np.ndarray | None:
        """The poses kept under `name` ("poses", "poses_no_loop", "poses_window") as F x 4 x 4 in the order
        of `indices`; None unless every one of them is there."""
        kept = getattr(self, name)
        if not indices or any(i not in kept for i in indices):
            return None
        return np.stack([np.array(kept[i]).reshape(4, 4) for i in indices])


@single_threaded_blas
def run_refine(seq: Sequence, cfg: RefineConfig, out: Path, resume: bool = False, progress: bool = True,
               pool: dict[str, DepthMetricAccumulator] | None = None, score: bool = True,
               collect: dict[int, FrameScore] | None = None) -> dict:
    """Refine every selected frame; returns the metrics dictionary (also written to metrics.json).
    `pool` (method -> accumulator) also receives every scored pixel, to pool metrics over sequences;
    `collect` receives each frame's FrameScore (benchmarks that score subsets of frames).
    `score=False` skips everything that reads ground truth (the self-supervised trainer's pose pass)."""
    from odometry.frontend import FrontEnd
    from odometry.initial_pose import first_step, is_spinning
    from odometry.mono_vo import MonoVO
    from odometry.motion_stereo import (FrameTracks, GrayImages, MotionStereoSettings, corrected_depth,
                                        motion_stereo_depth, neighbour_frames, pair_motions)
    from odometry.photo_field import PhotoFieldSettings, free_nodes, photometric_correction, photometric_offsets
    from odometry.sweep_motion import SweepMotion
    from odometry.window_graph import WindowGraph

    out = Path(out)
    ccfg = completion_config(cfg)
    indices = frame_indices(len(seq), ccfg)
    state_path = out / "progress.json"
    state = Progress.load(state_path) if resume and state_path.is_file() else Progress()
    # a resumed run replays its finished frames through the front end and the window (their outputs are
    # kept, not rewritten) so that the window, the landmarks and KISS-ICP's map are the uninterrupted run's
    names = seq.frame_numbers()
    done = {i for i in indices if i in state.poses and (out / "depth" / png_name(names, i)).is_file()}
    camera_only = cfg.input == "none"
    has_lidar = seq.has_lidar and not camera_only
    generator = generator_method(ccfg) if cfg.depth_source == "generator" else classical_source
    first = seq[indices[0]]
    K, shape = first.K, first.shape
    front = FrontEnd(cfg, K, shape, first.T_cam_lidar, use_lidar=has_lidar,
                     camera_height=None if has_lidar else road_height(seq, cfg))
    textbook = MonoVO(K) if cfg.compare else None  # the `mono_vo` baseline on the same images (--compare)
    gcfg = cfg if has_lidar else camera_only_graph_config(cfg)
    graph = WindowGraph(gcfg, K, shape, rng=np.random.default_rng(cfg.seed), condition_leaving=has_lidar)
    pending: dict[int, tuple[np.ndarray, float]] = {}  # generator depth, and the road's scale for it (camera only)
    replayed: dict[int, np.ndarray] = {}  # finished frames' poses as the replay found them
    empty: list[int] = []  # frames whose LiDAR input has no return inside the image
    scored: dict[int, FrameScore] = {}  # frames of this process, scored from their arrays
    stamps = seq.timestamps()
    checkpoint = generator_checkpoint(ccfg) if cfg.depth_source == "generator" else None
    start_run(out, "refine", run_identity("refine", cfg.model_dump(), [seq.path], checkpoint), resume,
              input=cfg.input if has_lidar else "none", sequence=str(Path(seq.path).resolve()),
              frame_numbers=names, **({} if has_lidar else {"camera_height_m": front.camera_height}))
    frame_dt = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.1

    def finish(results) -> None:
        leaving = {r.index: r.T_world_cam for r in results}  # at the end the whole window leaves at once
        for r in results:
            gen_depth, scale = pending.pop(r.index)
            if r.index in done:
                replayed[r.index] = r.T_world_cam
                continue
            refined = np.where(gen_depth > 0, gen_depth * scale * np.exp(r.log_offset), 0.0)
            if r.index in photo_free:  # where no return lies, the depth its neighbours' images agree with
                refined = photometric_step(r.index, r.T_world_cam, refined, leaving)
            if r.index in scored:
                scored[r.index].add("generator", gen_depth)
                scored[r.index].add("refined", refined)
            write_depth_png(out / "depth_generator" / png_name(names, r.index), gen_depth)
            write_depth_png(out / "depth" / png_name(names, r.index), refined)
            state.poses[r.index] = r.T_world_cam.ravel().tolist()
            state.save(state_path)

    desc = f"refine {input_label(cfg.input, has_lidar)} (window {cfg.window})"
    if done:
        desc += f", replaying {len(done)} finished"

    # a narrow-cone LiDAR's last scans, placed by the graph's poses, join the generator's input (spinning: off)
    history = ScanHistory(cfg.accumulate_frames if has_lidar else 0, first.T_cam_lidar, cfg.accumulate_check)

    def latest_poses(indices_kept: list[int]) -> dict[int, np.ndarray]:
        """The graph's current pose of each frame still in the window, else the pose it left with."""
        out = {}
        for j in indices_kept:
            if j in graph.poses:
                out[j] = graph.poses[j]
            elif j in replayed:
                out[j] = replayed[j]
            elif j in state.poses:
                out[j] = np.array(state.poses[j]).reshape(4, 4)
        return out

    following = dict(zip(indices[:-1], indices[1:]))
    # the photometric correction of a leaving frame: its neighbours' images and the nodes free to move
    position = {j: n for n, j in enumerate(indices)}
    photo = PhotoFieldSettings(min_gain=cfg.photometric_min_gain)
    photo_images = GrayImages(lambda j: stereo_image(seq, j), keep=cfg.window + 2 * max(cfg.photometric_offsets, default=0) + 3)
    photo_free: dict[int, np.ndarray] = {}

    def photometric_step(i: int, T_i: np.ndarray, depth: np.ndarray, leaving: dict[int, np.ndarray]) -> np.ndarray:
        """Frame i's refined depth after the plane sweep against the selected frames `photometric_offsets`
        before and after it (the poses they have now: final before i, the window's after it; `leaving`: the
        poses of the frames leaving with i)."""
        free = photo_free.pop(i)
        offsets = [-o for o in cfg.photometric_offsets] + ([] if cfg.causal else cfg.photometric_offsets)
        near = [indices[position[i] + o] for o in offsets if 0 <= position[i] + o < len(indices)]
        poses = latest_poses(near) | {j: leaving[j] for j in near if j in leaving}
        gray = photo_images[i]
        pairs = [(photo_images[j], invert_T(poses[j]) @ T_i) for j in near if j in poses]
        pairs = [(im, T) for im, T in pairs if im is not None and im.shape == depth.shape]
        if gray is None or not pairs:
            return depth
        return photometric_correction(depth, photometric_offsets(depth, gray, pairs, K, free, photo), photo)

    # motion stereo: image corners outside a cone LiDAR's reach, triangulated over neighbouring frames
    stereo = MotionStereoSettings()
    stereo_images = GrayImages(lambda j: stereo_image(seq, j), keep=2 * max(stereo.offsets + tuple(cfg.pair_offsets)) + 3)
    selected = set(indices)
    sensor: dict[str, bool] = {}  # "spinning", once judged on the first scan with returns

    def cone_step(setting: bool | str, sample: EvalSample) -> bool:
        """Whether a step that needs a LiDAR and is `auto` with a cone one (motion stereo, pair factors) runs."""
        if not has_lidar or setting is False:
            return False
        if setting is True:
            return True
        kept = sample.kept_points
        spinning = sensor.get("spinning")
        if spinning is None and kept is not None and len(kept) >= 100:
            spinning = is_spinning(kept[:, :3])
        return spinning is False

    sweep_images = SweepMotion()
    sweep_of: dict[int, np.ndarray | None] = {}  # frame -> its sweep's motion (to the next frame), set in `prepare`

    def next_frame(i: int, frame: Frame) -> Frame | None:
        """Frame i + 1 when it is the next selected one and frame i's scan has point times (its sweep ends
        there), else None; read once: the main thread then takes it from `reads`."""
        j = i + 1
        if frame.point_times is None or following.get(i) != j:
            return None
        if j not in reads:
            reads[j] = Future()
            reads[j].set_result(seq[j])
        return reads[j].result()

    def sweep(i: int, frame: Frame, motion: np.ndarray | None) -> np.ndarray | None:
        """The camera motion over frame i's sweep, to deskew it: the last step (`motion`, None before the
        second frame), or the motion read from this image and the next one (not in a causal run)."""
        nxt_frame = None if cfg.causal else next_frame(i, frame)
        if nxt_frame is None:
            return motion
        return sweep_images(i, frame.image, i + 1, nxt_frame.image, frame.K, motion)

    start: list[np.ndarray | None] = [None]  # the first step's motion, for the first two sweeps

    def start_motion(i: int, frame: Frame) -> np.ndarray | None:
        """The first step's motion from the first two cheap scans as they are (no step is known yet)."""
        nxt_frame = next_frame(i, frame)
        if nxt_frame is None:
            return None
        scans = [frame_sample(seq, k, ccfg, None, frame_dt, camera_only, truth=False, frame=f).kept_points
                 for k, f in ((i, frame), (i + 1, nxt_frame))]
        start[0] = first_step(*scans, frame.T_cam_lidar)
        return start[0]

    def prepare(i: int, motion: np.ndarray | None, earlier: np.ndarray | None
                ) -> tuple[EvalSample, np.ndarray, np.ndarray, float, dict[int, np.ndarray], np.ndarray | None]:
        """Frame i's input and generator depth; runs beside the graph update of the previous frame.
        `motion`: the last step (deskew on), else None; `earlier`: returns of the frames before, in frame i's
        predicted camera (the generator's input only)."""
        frame = reads.pop(i).result() if i in reads else seq[i]
        t_sweep = time.perf_counter()
        if cfg.deskew and has_lidar and i == indices[0] and not cfg.causal:
            motion = start_motion(i, frame)
        given = motion
        motion = sweep(i, frame, motion) if cfg.deskew else None
        # KISS-ICP's prediction for the next frame: the images' motion only where it overruled the last step
        # (the start and end of turns); elsewhere KISS-ICP keeps its own constant velocity
        sweep_of[i] = motion if motion is not given and given is not None else None
        sweep_s = time.perf_counter() - t_sweep  # counted with the generator: the same thread's per-frame work
        # the held-out truth is scoring, not refinement: built in the main thread's scoring step below
        sample = frame_sample(seq, i, ccfg, motion, frame_dt, camera_only, truth=False, frame=frame)
        t0 = time.perf_counter() - sweep_s
        if earlier is not None:
            earlier = history.keep_consistent(earlier, sample.kept_points)
        seen = sample if earlier is None else replace(sample, sparse=with_history(sample.sparse, earlier, sample.frame.K))
        corners, pairs, tracks = None, {}, None
        with_stereo, with_pairs = cone_step(cfg.motion_stereo, sample), cone_step(cfg.pair_factors, sample)
        if with_stereo or with_pairs:  # frame i's corners and tracks, shared by motion stereo and the pairs
            if i not in stereo_images.images:
                stereo_images.put(i, frame.image)
            tracks = FrameTracks(i, stereo_images, sample.frame.K, sample.sparse, stereo)
        if with_stereo:
            corners = motion_stereo_depth(i, neighbour_frames(i, indices, stereo.causal_offsets if cfg.causal else stereo.offsets, cfg.causal), stereo_images,
                                          sample.frame.K, sample.sparse, seen.sparse, stereo, tracks)
        depth, log_sigma = generator(seen)
        if corners is not None:  # the generator's depth moved towards the corners around them
            depth = corrected_depth(depth, corners, stereo.spread * float(sample.frame.K[0, 0]), stereo.support,
                                    stereo.range_log, stereo.edge_px)
        if with_pairs:  # the images' motion to the window's earlier frames
            pairs = pair_motions(i, [i - o for o in cfg.pair_offsets if i - o in selected], stereo_images,
                                 sample.frame.K, sample.sparse, stereo, tracks)
        return sample, depth, log_sigma, 1000.0 * (time.perf_counter() - t0), pairs, corners

    # frame k+1 is read and run through the generator in a second thread while the graph optimises frame k
    # (ONNX Runtime and OpenCV leave the interpreter lock); its inputs are known once the front
    # end has processed frame k (the deskew motion), so the results are those of a sequential run
    # (one core's worth of threads, as in a batch task with one CPU: sequential, in this thread)
    ahead = ThreadPoolExecutor(max_workers=1, thread_name_prefix="leovr-generator") if torch_threads() > 1 else None
    # and its files are read (image decoding leaves the interpreter lock) while this frame's front end runs
    reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="leovr-read") if ahead is not None else None
    reads: dict[int, Future] = {}

    def submit(i: int, motion: np.ndarray | None, earlier: np.ndarray | None = None) -> Future:
        if ahead is not None:
            return ahead.submit(prepare, i, motion, earlier)
        fut: Future = Future()
        try:
            fut.set_result(prepare(i, motion, earlier))
        except Exception as exc:  # raised where the frame is used, as from the thread
            fut.set_exception(exc)
        return fut

    nxt = None
    t_end = time.perf_counter()
    try:
        for n, i in enumerate(tqdm(indices, desc=desc, unit="frame", disable=not progress)):
            if nxt is None:
                nxt = submit(i, front.velocity if front.prev is not None else None)
            sample, depth, log_sigma, gen_ms, pairs, corners = nxt.result()
            nxt = None
            if reader is not None and n + 1 < len(indices) and indices[n + 1] not in reads:
                reads[indices[n + 1]] = reader.submit(seq.__getitem__, indices[n + 1])
            if has_lidar and i not in done and not (sample.sparse > 0).any():
                empty.append(i)
            t1 = time.perf_counter()
            prev_i = indices[n - 1] if n else None
            guess = sweep_of.pop(prev_i, None)  # the previous sweep's motion, read from its images: to this frame
            # spinning LiDARs only: measured there (a cone's KISS-ICP pose only competes with PnP as the initial pose)
            spinning_now = sensor.get("spinning") is True
            guess = guess if spinning_now else None
            fi = front.process(i, sample.frame.image, depth, log_sigma, sample.sparse if has_lidar else None,
                               sample.kept_points, graph, icp_guess=guess)
            fi.pair_motions = pairs
            if i not in done and cone_step(cfg.photometric_field, sample):
                photo_images.put(i, sample.frame.image)
                photo_free[i] = free_nodes(sample.sparse, photo)
            if corners is not None:
                cv, cu = np.nonzero(corners > 0)
                fi.stereo_uvz = np.column_stack([cu, cv, corners[cv, cu]]).astype(float)
            t2 = time.perf_counter()
            if not history.sensor_known and sample.kept_points is not None and len(sample.kept_points) >= 100:
                # judged on the first scan with returns: a spinning sensor keeps its own scan, and with
                # `depth_factors: auto` the graph leaves the depth to the generator
                history.sensor_known = True
                spinning = is_spinning(sample.kept_points[:, :3])
                sensor["spinning"] = spinning
                if spinning:
                    history.frames = 0
                if cfg.depth_factors == "auto":
                    graph.depth_factors = not spinning
            history.add(i, sample.kept_points)
            if n + 1 < len(indices):
                earlier = None
                if history.frames and history.sensor_known:  # the next frame's pose predicted at constant velocity
                    poses = latest_poses([s.index for s in history.scans]) | {i: fi.T_init}
                    earlier = history.gather(poses, fi.T_init @ front.velocity)
                # after the first frame no step is known yet: the first two scans' own motion
                velocity = start[0] if n == 0 and start[0] is not None else front.velocity
                nxt = submit(indices[n + 1], velocity, earlier)
            pending[i] = depth, front.depth_scale
            t_base = time.perf_counter()  # the scoring and the baselines below are not part of a frame's time
            fs = FrameScore.of(with_truth(sample, ccfg)) if score and i not in done else None
            if fs is not None:
                scored[i] = fs
            if fs is not None and history.frames:
                fs.own_input = (*np.nonzero(sample.sparse), sample.sparse[sample.sparse > 0])
            if has_lidar and i not in done:  # the classical baselines on the very same input, for the metrics (not timed)
                ipb = complete_depth(sample.sparse, "ipbasic")
                write_depth_png(out / "depth_ipbasic" / png_name(names, i), ipb)
                if fs is not None:
                    fs.add("ipbasic", ipb)
                    fs.add("nearest", complete_depth(sample.sparse, "nearest"))
            t2b = time.perf_counter()
            left = graph.add_frame(fi)
            t3 = time.perf_counter()
            finish([graph.current(i)] if cfg.causal else left)  # causal: the newest frame's estimate is its output
            t4 = time.perf_counter()
            if textbook is not None:
                textbook.add(sample.frame.image)
            # wall: this frame's share of the run's clock (baselines excluded), the generator overlapping the graph
            wall = 1000.0 * ((t4 - t_end) - (t2b - t_base))
            t_end = time.perf_counter()
            if i in done:
                continue
            state.sources[i] = front.sources[-1]
            if front.prev is not None and front.prev.T_icp is not None:
                state.icp_poses[i] = front.prev.T_icp.ravel().tolist()
            state.times[i] = [gen_ms, 1000.0 * (t2 - t1), 1000.0 * (t3 - t2b), 1000.0 * (t4 - t3), wall]
    finally:
        if nxt is not None:
            nxt.cancel()
        if ahead is not None:
            ahead.shutdown(wait=True)
        if reader is not None:
            reader.shutdown(wait=True, cancel_futures=True)
    left = graph.flush()
    if not cfg.causal:
        finish(left)
    several = [i for i, fs in scored.items() if fs.own_input is not None]  # earlier scans joined the generator's input
    single_frame_generator(seq, scored, generator, progress)
    if empty:
        warn_empty_input(seq, empty)
    if replayed:
        check_replay(out, state, replayed)
    landmarks, seen_by = graph.all_landmarks()

    def move_poses(before: np.ndarray, after: np.ndarray) -> None:
        """A whole-recording pass moved the poses: keep them, and move each landmark with the frame that
        last observed it."""
        state.poses = {i: T.ravel().tolist() for i, T in zip(indices, after)}
        moves = after @ np.stack([invert_T(T) for T in before])  # per frame: its old pose to its new one
        order = np.argsort(indices)
        at = np.searchsorted(np.asarray(indices)[order], seen_by).clip(0, len(indices) - 1)
        n = order[at]
        mine = np.asarray(indices)[n] == seen_by  # landmarks whose frame is one of the poses
        D = moves[n[mine]]
        landmarks[mine] = np.einsum("nij,nj->ni", D[:, :3, :3], landmarks[mine]) + D[:, :3, 3]

    if not cfg.causal and not has_lidar and front.camera_height and cfg.mono_length_smoothing and len(indices) > 2:
        before = state.stacked("poses", indices)
        state.poses_window = {i: T.ravel().tolist() for i, T in zip(indices, before)}
        after = smoothed_step_lengths(before, indices, front.length_readings, cfg)
        move_poses(before, after)
    if cfg.loop_closure:
        from leovr.pipeline.loops import loop_pass

        before = state.stacked("poses", indices)
        corrected, _, _ = loop_pass(seq, out, indices, before, cfg.loop_min_gap, cfg.vocabulary, cfg.loop_odometry_cauchy)
        state.poses_no_loop = {i: T.ravel().tolist() for i, T in zip(indices, before)}
        move_poses(before, corrected)
    state.save(state_path)
    atomic_write(out / "landmarks.npy", lambda tmp: np.save(open(tmp, "wb"), landmarks))
    atomic_write(out / "landmarks_frame.npy", lambda tmp: np.save(open(tmp, "wb"), seen_by))
    lidar_backed = graph.lidar_backed()
    atomic_write(out / "landmarks_lidar.npy", lambda tmp: np.save(open(tmp, "wb"), lidar_backed))
    baselines: dict[str, tuple[np.ndarray, str]] = {}
    if textbook is not None:
        baselines["mono_vo"] = np.stack(textbook.poses), "sim3"
        write_kitti_poses(out / "poses_mono_vo_kitti.txt", baselines["mono_vo"][0])
    icp = None
    if has_lidar and (cfg.compare or several or score and first.T_world_cam is not None):
        icp = kiss_icp_trajectory(seq, indices, ccfg, progress)
        if icp is not None:
            baselines["kiss_icp"] = icp, "se3"
            write_kitti_poses(out / "poses_kiss_icp_kitti.txt", icp)
        if icp is not None and first.point_times is not None:  # KISS-ICP without its deskew, the other way to run it
            baselines["kiss_icp_no_deskew"] = kiss_icp_trajectory(seq, indices, ccfg, progress, deskew=False), "se3"
            write_kitti_poses(out / "poses_kiss_icp_no_deskew_kitti.txt", baselines["kiss_icp_no_deskew"][0])
    if several and icp is not None:  # the fills given the same frames: the yardstick for a cone's several scans
        accumulated_fills(seq, indices, ccfg, icp, scored, several, cfg.accumulate_frames, causal=cfg.causal,
                          frame_dt=frame_dt, progress=progress)
    return write_outputs(seq, cfg, ccfg, indices, state, out, has_lidar, progress, pool, score, scored, collect,
                         baselines)


def smoothed_step_lengths(poses: np.ndarray, indices: list[int], readings: dict, cfg: RefineConfig) -> np.ndarray:
    """Camera only: the window pass's poses with each step's length solved again over the whole recording
    from the road's readings (`odometry.step_length`); rotations and directions of travel are kept."""
    from odometry.step_length import rescale_steps, smooth_log_lengths

    chain = [readings.get(i) for i in indices[1:]]
    return rescale_steps(poses, np.exp(smooth_log_lengths(chain, cfg.mono_length_change_sigma_m)))


def camera_only_graph_config(cfg: RefineConfig) -> RefineConfig:
    """The graph's settings without LiDAR: the generator's depth, far less sure without LiDAR, gets the
    camera-only landmark prior and depth-consistency sigma."""
    return cfg.model_copy(update={"landmark_prior_rel": cfg.mono_landmark_prior_rel,
                                  "consistency_sigma_log": cfg.mono_consistency_sigma_log})


def road_height(seq: Sequence, cfg: RefineConfig) -> float | None:
    """The camera's height above the road for camera-only runs: the config's, else the recording's;
    None (or 0 in the config): unknown, the generator's depth sets the scale."""
    h = cfg.camera_height_m if cfg.camera_height_m is not None else seq.camera_height_m
    return h if h else None


def check_replay(out: Path, state: Progress, replayed: dict[int, np.ndarray], tol_m: float = 0.05) -> None:
    """Warn when replaying the finished frames of a resumed run did not give back the poses written
    before the interruption (another leovr version, or the recording changed in between)."""
    written = state.poses_window or state.poses_no_loop or state.poses  # as the window pass left them
    gap = {i: float(np.linalg.norm(T[:3, 3] - np.array(written[i]).reshape(4, 4)[:3, 3])) for i, T in replayed.items()
           if i in written}
    if not gap:
        return
    worst = max(gap, key=gap.get)
    if gap[worst] > tol_m:
        warnings.warn(f"{out}: resuming replayed the finished frames but frame {worst}'s pose moved {gap[worst]:.2f} m "
                      "from the one written before the interruption; the outputs mix two runs: rerun without --resume",
                      stacklevel=2)


def input_label(name: str, has_lidar: bool) -> str:
    """What the progress bar and metrics say the graph runs on."""
    if name == "none":
        return "camera only (the recording's LiDAR held out)"
    if not has_lidar:
        return "camera only (no LiDAR)"
    return "own scan" if name == "full" else f"{name} simulated from the scan"


def single_frame_generator(seq: Sequence, scored: dict[int, "FrameScore"], generator, progress: bool) -> None:
    """`generator_frame` for the scored frames whose generator input held earlier scans: the generator on
    the frame's own scan alone, the same-run yardstick for what the earlier scans and the graph add."""
    todo = [i for i, fs in scored.items() if fs.own_input is not None]
    for i in tqdm(todo, desc="score single-frame generator", unit="frame", disable=not progress or not todo):
        fs = scored[i]
        f = seq[i]
        sparse = np.zeros(f.shape, np.float32)
        rows, cols, z = fs.own_input
        sparse[rows, cols] = z
        fs.add("generator_frame", generator(EvalSample(f, sparse, sparse, "none"))[0])
        fs.own_input = None


def frame_score(seq: Sequence, ccfg: CompleteConfig, out: Path, i: int, has_lidar: bool) -> FrameScore | None:
    """Score of a frame finished before a resume: its maps read back from the PNGs at the run's scale."""
    sample = frame_sample(seq, i, ccfg, camera_only=not has_lidar)
    fs = FrameScore.of(sample)
    if fs is None:
        return None
    if has_lidar:
        fs.add("nearest", complete_depth(sample.sparse, "nearest"))
    for method, folder in PNG_FOLDER.items():
        if method != "ipbasic" or has_lidar:
            fs.add(method, read_run_depth(out, folder, i, sample.frame.shape))
    return fs


def timing_record(times: dict[int, list[float]], indices: list[int]) -> dict:
    """timing.json: per stage the mean (`generator_ms`, ...), median, p95 and max over the frames, and
    the per-frame series (to see whether a stage grows along the sequence). Runs from before a stage was
    recorded (the output stage, the wall time) have none for it: NaN in the series, left out of the stats."""
    timed = [i for i in indices if i in times]
    width = len(TIMED) + 1
    ms = np.array([list(times[i])[:width] + [np.nan] * (width - len(times[i])) for i in timed], float).reshape(-1, width)
    stages = ({k: np.nan_to_num(ms[:, n]) for n, k in enumerate(TIMED)}
              | {"total_ms": np.nansum(ms[:, :len(TIMED)], axis=1), WALL: ms[:, len(TIMED)]})
    record: dict = {k: float(np.mean(v)) if len(v) and np.isfinite(v).all() else None for k, v in stages.items()}
    record["frames_timed"] = len(timed)
    record["stats"] = {k: {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max())}
                       for k, v in stages.items() if len(v) and np.isfinite(v).all()}
    record["series"] = {"frame": timed} | {k: [None if not np.isfinite(x) else round(float(x), 2) for x in v]
                                           for k, v in stages.items()}
    return record


def write_outputs(seq: Sequence, cfg: RefineConfig, ccfg: CompleteConfig, indices: list[int], state: Progress,
                  out: Path, has_lidar: bool, progress: bool, pool: dict | None = None, score: bool = True,
                  scored: dict[int, FrameScore] | None = None, collect: dict[int, FrameScore] | None = None,
                  baselines: dict[str, tuple[np.ndarray, str]] | None = None) -> dict:
    """Poses in KITTI and TUM form, timing, and depth / trajectory metrics. Depth is scored from the
    arrays the run produced (`scored`); frames finished before a resume are read back from their PNGs.
    `baselines` (name -> poses of the same frames and their alignment, "sim3" for a monocular one) are
    scored beside leovr's trajectory."""
    poses = np.stack([np.array(state.poses[i]).reshape(4, 4) for i in indices])
    stamps = seq.timestamps()[indices]
    write_kitti_poses(out / "poses_kitti.txt", poses)
    write_tum_poses(out / "poses_tum.txt", stamps, poses)
    counts = {s: list(state.sources.values()).count(s) for s in sorted(set(state.sources.values()))}
    timing = timing_record(state.times, indices)
    timing["initial_pose_sources"] = counts
    write_text(out / "timing.json", json.dumps(timing, indent=2) + "\n")
    accs = {m: DepthMetricAccumulator(cfg.bins) for m in SCORED}
    scored = scored or {}
    kinds, gt_poses = set(), []
    frame_scores = []
    for i in tqdm(indices if score else [], desc="score", unit="frame", disable=not progress):
        gt_poses.append(seq[i].T_world_cam)
        fs = scored[i] if i in scored else frame_score(seq, ccfg, out, i, has_lidar)
        if fs is not None:
            frame_scores.append(fs)
            if collect is not None:
                collect[i] = fs
    partial = {m for m in SCORED if 0 < sum(m in fs.pred for fs in frame_scores) < len(frame_scores)}
    for fs in frame_scores:  # a method some frames lack (a resumed run's single-frame generator) is left out
        kinds.add(fs.kind)
        for method, pred in fs.pred.items():
            if method in partial:
                continue
            for target in (accs, pool or {}):
                if method in target:
                    target[method].add(pred, fs.gt)
    metrics: dict = {
        "sequence": str(Path(seq.path).resolve()), "reader": seq.name, "input": cfg.input if seq.has_lidar else "none (no LiDAR)",
        "input_note": input_label(cfg.input, has_lidar),
        "frames": len(indices), "window": cfg.window, "causal": cfg.causal,
        "mode": "visual-LiDAR" if has_lidar else input_label(cfg.input, has_lidar),
        "ground_truth": "; ".join(ground_truth_note(k, ccfg) for k in sorted(kinds)),
        "depth": {m: a.result() for m, a in accs.items() if not a.empty},
        "timing": {k: v for k, v in timing.items() if k != "series"},  # the series is in timing.json
    }
    if score and all(T is not None for T in gt_poses) and len(indices) >= 3:
        ref = np.stack([invert_T(gt_poses[0]) @ T for T in gt_poses])
        align = "se3" if has_lidar else "sim3"
        metrics["trajectory"] = {"leovr": trajectory_metrics(poses, ref, align)}
        for name, kept in (("leovr_no_loop", "poses_no_loop"), ("leovr_window", "poses_window")):
            earlier = state.stacked(kept, indices)  # before a whole-recording pass moved them, when one did
            if earlier is not None:
                metrics["trajectory"][name] = trajectory_metrics(earlier, ref, align)
        for name, (est, how) in (baselines or {}).items():
            metrics["trajectory"][name] = trajectory_metrics(est, ref, how)
    write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    return metrics
