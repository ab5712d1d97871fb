"""``assembly-agent odometry RECORDING --out TRAJ.tum``: estimate the camera's ego-motion over a recording.

Writes one line per frame in the TUM format (``timestamp tx ty tz qx qy qz qw``: the camera's pose in the world
frame = the first frame's camera frame, metres, Hamilton quaternion; timestamps = the frames' ``t``). Frames that
cannot be measured — no depth, an unreadable or corrupt image, a failed alignment — are reported on stderr and
get the constant-velocity pose, flagged by a ``#`` comment on the line before them, so the trajectory has a pose
for every frame.

``--method default`` is the dense RGB-D odometry, ``--method fastslam`` the seed's AKAZE + FastSLAM 1.0, ``--method
parts`` the camera pose from the parts of objects.json that stay put (the tracker of ``track`` runs on the frames;
:mod:`tracker.odometry.part_landmarks`; parts without a first-frame pose are found as ``track`` finds them; the
mask does not apply). A frame on which no resting part agrees keeps the last pose (flagged). ``--method fused`` runs
both, the dense odometry (with ``--mask``) and the tracker, and lets them check each other
(:mod:`tracker.odometry.fused_odometry`); frames held on the constant-velocity prediction are flagged.
``--mask`` chooses what is excluded from the static scene: ``hand`` (default) the hand's box when the recording's
ground truth has one (simulated recordings), else the hands the hand tracker finds in the colour images
(:mod:`tracker.odometry.hand_exclusion`, run in the decoding thread), ``parts`` also the colour-detected parts of
objects.json, ``none`` nothing (the robust weights alone then deal with hands and moving parts). When the recording
has the simulator's ``camera_pose`` ground truth, ATE / rotation / RPE errors are printed.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ODOMETRY_PARTICLES = 100
"""N of the part tracker run by ``--method parts`` / ``fused``: the odometry needs only the resting parts, which the
tracker's dense refinement holds to a fraction of a millimetre at any N; with the preset's 225 the trajectory was
the same to within ±0.1 mm ATE on five tuning sessions (hand-held camera, seeds 0–4) at 10–20 % more CPU."""


def register(subparsers) -> None:
    p = subparsers.add_parser("odometry", help="estimate the camera's motion over a recording (TUM trajectory)")
    p.add_argument("recording", help="recording directory (README 'Recording format')")
    p.add_argument("--out", required=True, help="output trajectory file (TUM format)")
    p.add_argument("--method", default="default", choices=("default", "fastslam", "parts", "fused"),
                   help="default: dense RGB-D odometry; fastslam: AKAZE features + FastSLAM 1.0 (the seed); parts: "
                        "from the tracked parts that stay put (objects.json); fused: dense and parts checking each "
                        "other")
    p.add_argument("--mask", default="hand", choices=("hand", "parts", "none"),
                   help="what to exclude: hand (the ground-truth hand box when recorded, else the hands the hand "
                        "tracker finds), parts (also colour-detected parts), none")
    p.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--seed", type=int, default=0, help="random seed (point sampling, particles)")
    p.add_argument("--particles", type=int, default=ODOMETRY_PARTICLES,
                   help=f"N of the part tracker that --method parts / fused run (default {ODOMETRY_PARTICLES})")
    p.set_defaults(func=run)


def _part_detector(src, mode: str):
    if mode != "parts":
        return None
    from tracker.perception.color_detection import ColorDetector

    coloured = [p for p in src.parts if p.color is not None]
    return ColorDetector.from_parts(coloured) if coloured else None


def _part_tracker(recording: str, seed: int, particles: int | None):
    """The tracker of ``track`` on the recording's parts (parts without a first-frame pose found as ``track`` finds
    them), at ``particles`` N; returns the TrackSession and each part's corner points (M, 3) in its body frame."""
    from app.commands.track import TrackSession, _auto_poses, load_recording_parts
    from tracker.filter.tracker_config import TrackerConfig

    src, parts, poses = load_recording_parts(recording)
    try:
        missing = [p for p in parts if p.name not in poses]
        table = None
        if missing:
            poses, table = _auto_poses(src, parts, missing, dict(poses), True)
    finally:
        src.close()
    cfg = TrackerConfig.preset("default")
    if particles is not None:
        cfg = cfg.with_overrides(n_particles=particles)
    session = TrackSession(parts, src.intrinsics, poses, cfg, seed=seed, table=table)
    trk = session.tracker
    return session, {name: trk.corners[i] for i, name in enumerate(trk.names)}


class _PartsOdometry:
    """``--method parts``: the tracker of ``track`` on the recording's parts, the camera pose from its resting ones
    (the odometry interface: ``step(frame, mask)`` and ``skip(timestamp, reason)`` give an OdometryResult)."""

    def __init__(self, recording: str, seed: int, particles: int | None = None) -> None:
        from tracker.odometry.part_landmarks import PartLandmarkOdometry

        self.session, self.corners = _part_tracker(recording, seed, particles)
        self.landmarks = PartLandmarkOdometry()

    def _result(self, pose, ok: bool, t0: float, timestamp: float, message: str):
        from tracker.odometry.odometry_result import OdometryResult

        return OdometryResult(pose, ok, self.landmarks.used, 1e3 * (time.perf_counter() - t0), float(timestamp),
                              message=message)

    def step(self, frame, mask=None):
        t0 = time.perf_counter()
        if frame.depth is None:
            return self.skip(frame.timestamp, f"frame {frame.index}: no depth image — last pose kept")
        self.session.step(frame)
        pose = self.landmarks.update(self.session.tracker.landmark_poses, self.corners)
        ok = self.landmarks.used > 0
        return self._result(pose, ok, t0, frame.timestamp,
                            "" if ok else f"frame {frame.index}: no resting part agreed — last pose kept")

    def skip(self, timestamp: float, reason: str):
        from tracker.geometry.pose import Pose

        pose = self.landmarks.pose_world_camera or Pose()
        return self._result(pose, False, time.perf_counter(), timestamp, reason)


FUSED_PATH_PROCESS = True
"""``--method fused`` runs the camera's path in a child process (:class:`app.commands.camera_path.CameraPathProcess`);
False: in the calling thread, one job after the other (the reference the tests compare it with)."""


class _FusedOdometry:
    """``--method fused``: the dense odometry and the tracker's resting parts checking each other
    (:class:`tracker.odometry.fused_odometry.FusedOdometry`).

    The part tracker runs in the calling thread, the camera's path (:mod:`app.commands.camera_path`) in a child
    process: frame k's dense alignment beside frame k's tracker step, frame k's fusion beside frame k + 1's. The
    tracker needs nothing of the path, so each frame's pose is the same to the last bit as with the jobs run at once
    in the calling thread; only it comes later: :meth:`step` and :meth:`skip` return a
    :class:`~concurrent.futures.Future` of the frame's OdometryResult."""

    def __init__(self, recording: str, seed: int, intrinsics, particles: int | None = None) -> None:
        from app.commands.camera_path import CameraPathProcess, InlineCameraPath

        self.session, self.corners = _part_tracker(recording, seed, particles)
        kind = CameraPathProcess if FUSED_PATH_PROCESS else InlineCameraPath
        self.path = kind(intrinsics, seed, self.corners)

    def step(self, frame, mask=None):
        if frame.depth is None:
            return self.skip(frame.timestamp, f"frame {frame.index}: no depth image — pose extrapolated")
        self.path.dense(frame, mask)  # neither side writes to the frame
        self.session.step(frame)
        table = self.session.table
        return self.path.fuse(self.session.tracker.landmark_poses,
                              None if table is None else (table.normal, table.offset))

    def skip(self, timestamp: float, reason: str):
        return self.path.skip(timestamp, reason)

    def close(self) -> None:
        """Finish the queued jobs and stop the camera path."""
        self.path.close()


@dataclass
class TrajectoryRun:
    """What :func:`estimate_trajectory` measured: one TUM row per frame, the recorded ground truth, timing.

    * ``rows``: ``(timestamp s, camera pose in the world frame = first camera frame, comment)``; comment non-empty for
      a frame that was not measured (pose extrapolated or held).
    * ``truth``: the recording's ``camera_pose`` ground truth of each frame (simulated recordings) or ``None``.
    * ``wall_s``: seconds from the first read to the last pose; ``cpu_ms``: main-thread CPU per frame (ms; the
      decoding of the next frames runs in another thread beside it, and with ``fused`` the camera's path in a child
      process).
    """

    rows: list[tuple[float, Any, str]] = field(default_factory=list)
    truth: list[Any] = field(default_factory=list)
    wall_s: float = 0.0
    cpu_ms: float = 0.0
    flagged: int = 0

    @property
    def fps(self) -> float:
        return len(self.rows) / max(self.wall_s, 1e-9)

    def errors(self) -> dict | None:
        """ATE / rotation / RPE against the recorded camera poses (:func:`trajectory_errors` as a dict), or None
        when the recording has none for its first frame."""
        have = [i for i, t in enumerate(self.truth) if t is not None]
        if not have or have[0] != 0:
            return None
        from tracker.evaluation.trajectory_errors import trajectory_errors

        w0 = self.truth[0].inverse()
        errs = trajectory_errors([self.rows[i][0] for i in have], [self.rows[i][1] for i in have],
                                 [w0 @ self.truth[i] for i in have])
        return errs.to_dict()


def _hand_finder(src, mask_mode: str, method: str, seed: int):
    """The hand tracker's exclusion (:class:`tracker.odometry.hand_exclusion.HandExclusion`) when hands are to be
    masked (``--mask hand`` or ``parts``), the method uses the mask (not ``parts``) and the recording has no
    ground-truth hand boxes (a real camera's); else None."""
    if mask_mode == "none" or method not in ("default", "fastslam", "fused") or len(src) == 0:
        return None
    first = src.groundtruth_record(src.index_at(0))
    if first is not None and "hand_box" in first:  # simulated: the recorded boxes are used
        return None
    from tracker.odometry.hand_exclusion import HandExclusion

    return HandExclusion(src.intrinsics, seed=seed)


def _analysed(frame, hands):
    """``hands(frame.color)``, taken from the frame's colour analysis when the decoding thread already ran it."""
    done = frame.meta.get("colour_analysis")
    return done[1] if done is not None and done[0] is hands else hands(frame.color)


def estimate_trajectory(recording: str, method: str = "default", mask_mode: str = "hand", frames: int | None = None,
                        seed: int = 0, particles: int | None = ODOMETRY_PARTICLES, report=None,
                        odometry=None) -> TrajectoryRun:
    """Run one odometry ``method`` over a recording as ``assembly-agent odometry`` does (decoding included).

    ``report(message)`` gets each frame's problem (a skipped frame, an extrapolated pose); the run goes on.
    ``odometry``: a ready object with ``step(frame, mask)`` and ``skip(timestamp, reason)`` (e.g. a benchmark's
    baseline) run instead of ``method``'s."""
    from tracker.geometry.pose import Pose
    from tracker.odometry import make_odometry
    from tracker.odometry.exclusion_mask import exclusion_mask
    from tracker.sources.base import SourceError
    from tracker.sources.recording import RecordingSource

    if frames is not None and frames < 1:
        raise ValueError("--frames must be at least 1")
    if particles is not None and particles < 1:
        raise ValueError("--particles must be at least 1")
    src = RecordingSource(recording)
    odo = odometry
    try:
        detector = _part_detector(src, mask_mode)
        if odo is not None:
            pass
        elif method == "parts":
            odo = _PartsOdometry(recording, seed, particles)
        elif method == "fused":
            odo = _FusedOdometry(recording, seed, src.intrinsics, particles)
        else:
            odo = make_odometry(method, src.intrinsics, seed=seed)
        session = getattr(odo, "session", None)
        if session is not None and session.detector is not None:  # parts / fused: the tracker's colour detection
            src.analyse_colour(session.detector.detect)  # of the next frames, as they are decoded ahead
        hands = _hand_finder(src, mask_mode, method if odometry is None else "", seed)
        if hands is not None and src.analyse_colour_fn is None:  # the hand tracker on the next frames as they are
            src.analyse_colour(hands)  # decoded ahead (in order: it keeps its tracks from frame to frame)
        n = len(src) if frames is None else min(len(src), frames)
        run = TrajectoryRun()
        pending: deque = deque()  # results (or futures of them: fused) of frames not yet in run.rows, in order

        def record(wait: bool) -> None:
            """Move the pending results to run.rows in frame order: all (``wait``) or those ready now."""
            while pending and (wait or not isinstance(pending[0], Future) or pending[0].done()):
                res = pending.popleft()
                res = res.result() if isinstance(res, Future) else res
                if not res.ok:
                    run.flagged += 1
                    if report is not None:
                        report(res.message)
                run.rows.append((res.timestamp, res.pose_world_camera,
                                 "" if res.ok else f"extrapolated: {res.message}"))

        t_start, cpu_start = time.perf_counter(), time.thread_time()
        for pos in range(n):
            ts = src.timestamp(pos)
            try:
                frame = src.read(pos)
            except SourceError as exc:
                pending.append(odo.skip(ts, f"frame at line {pos + 1} skipped: {exc} — pose extrapolated at constant "
                                            "velocity"))
                run.truth.append(None)
            else:
                gt = frame.meta.get("groundtruth") or {}
                run.truth.append(gt.get("camera_pose") if isinstance(gt.get("camera_pose"), Pose) else None)
                mask = None
                found = None if hands is None else _analysed(frame, hands)
                if mask_mode != "none" and frame.depth is not None:
                    hand_box = gt.get("hand_box")
                    parts = detector.masks(frame.color).values() if detector is not None else ()
                    if hand_box is not None or detector is not None:
                        mask = exclusion_mask(frame.color.shape[:2], hand_box, parts)
                    if found is not None:
                        mask = found if mask is None else mask | found
                pending.append(odo.step(frame, mask))
            record(wait=False)
        record(wait=True)
        run.wall_s = time.perf_counter() - t_start
        run.cpu_ms = 1e3 * (time.thread_time() - cpu_start) / max(len(run.rows), 1)
    finally:
        if isinstance(odo, _FusedOdometry):
            odo.close()
        src.close()
    return run


def run(args: argparse.Namespace) -> int:
    from tracker.odometry.tum_trajectory import write_tum

    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {out} is a directory; give a file name such as traj.tum")
    result = estimate_trajectory(args.recording, args.method, args.mask, args.frames, args.seed, args.particles,
                                 report=lambda m: print(f"odometry: {m}", file=sys.stderr))
    header = (f"camera trajectory of {Path(args.recording)} by assembly-agent odometry --method {args.method}\n"
              "timestamp tx ty tz qx qy qz qw (camera pose in the world frame = first camera frame; metres)")
    write_tum(out, result.rows, header)
    print(f"wrote {len(result.rows)} poses to {out} ({result.flagged} extrapolated); {result.fps:.1f} frames/s "
          f"({args.method}; {result.cpu_ms:.1f} ms CPU per frame in the main thread, the next frames decoded "
          "beside it)")
    d = result.errors()
    if d is not None:
        print(f"against the recorded camera_pose ({sum(t is not None for t in result.truth)} frames): ATE RMSE "
              f"{d['ate_rmse_mm']} mm (max {d['ate_max_mm']}), rotation RMSE {d['rot_rmse_deg']}°, RPE "
              f"{d['rpe_mm_per_s']} mm/s, {d['rpe_deg_per_s']}°/s")
    return 0
