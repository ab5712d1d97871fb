"""Multi-object 6-DoF depth tracker: the coordinate particle filter of Algorithm 5 (spec sections 4 and 9).

Per frame (camera frame, metres, seconds):

1. colour control input u per part (4.38–4.40) from the colour detections (optional);
2. deterministic prediction of every part (noise 0) and the evaluated pixel set: the valid pixels of the
   depth image subsampled by ``downsample`` inside the parts' projected bounding rectangles (all particles,
   plus a noise margin); predicted occlusion probabilities ô per particle and pixel (4.8, Δt rate form);
3. for each part k in turn (Algorithm 5): sample its noise, propagate it (4.26), force connection particles
   (Algorithm 6), re-render what changed (exact box slab test or mesh rasterisation, z-buffer over all parts),
   update the per-particle log-likelihood ℓ (relative to the no-object hypothesis) plus the log penalties
   (intersection, table sinking), multiply the carried weights by exp(ℓ_k − ℓ_k−1) (ℓ_0 = 0 each frame), and
   resample (systematic) when D_KL(w‖U) > D_KL,max — copying poses, velocities, previous poses, rendered depths,
   cached pixel terms, ô and the occlusion posteriors with the particles;
4. occlusion posterior update (4.45) and the estimate (weighted mean position, rotation mean);
5. refinement of every visible part by dense-depth Gauss-Newton and re-acquisition of lost parts; the particles
   follow the correction (:mod:`tracker.refine.refine_stage`).

Each stage is a module of :mod:`tracker.filter` (``colour_input``, ``hidden_parts``, ``predict``, ``render``,
``weigh``) or :mod:`tracker.refine`; this class holds the particles and the per-part state between frames.

All-NaN depth (or no evaluated pixel): the update is skipped, the prediction kept, and the returned state says
so (``depth_used`` False, ``message``). Use :class:`MultiObjectTracker` as::

    tracker = MultiObjectTracker(parts, intrinsics, TrackerConfig.preset("default"), seed=0)
    tracker.initialize(first_poses)
    state = tracker.step(frame, detections, table)
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from tracker.filter import (
    blob_follow,
    colour_input,
    hand_carry,
    hidden_parts,
    predict,
    quiet_parts,
    render,
    scene_motion,
    weigh,
)
from tracker.filter.connection_particles import ResolvedConnection, resolve_hints
from tracker.filter.depth_likelihood import (
    LikelihoodParams,
    finish_occlusion,
    finish_occlusion_into,
    pixel_constants,
    update_log_likelihood,
)
from tracker.filter.frame_context import FrameContext, PassResult, table_normal_offset
from tracker.filter.hand_carry import HandCarry
from tracker.filter.motion_model import mean_poses, propagate, sample_noise
from tracker.filter.penalties import intersection_log_penalty
from tracker.filter.resampling import normalize_log_weights
from tracker.filter.tracker_config import TrackerConfig
from tracker.frame import Frame
from tracker.geometry.box_renderer import pixel_rays
from tracker.geometry.camera import Intrinsics
from tracker.geometry.mesh_renderer import MeshModel
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.refine import contact_align, refine_stage
from tracker.refine.icp_refinement import PartSurfaceModel
from tracker.refine.recovery import LossMonitor


@dataclass
class TrackerState:
    """Result of one :meth:`MultiObjectTracker.step`.

    * ``poses``: estimated pose of every part (camera frame).
    * ``particles``: per part, (N, 3) float32 particle positions (camera frame, metres).
    * ``weights``: (N,) normalised particle weights.
    * ``timings``: milliseconds per stage (``total``, ``predict``, ``render``, ``likelihood``, ``resample``…).
    * ``depth_used``: False when the update was skipped (no valid depth near the parts); ``message`` says why.
    * ``resampled``: how many of the N_obj passes resampled.
    * ``carried``: hidden parts taken to be in a hand and moved with it (:mod:`tracker.filter.hand_carry`).
    """

    index: int
    timestamp: float
    poses: dict[str, Pose]
    particles: dict[str, np.ndarray]
    weights: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    depth_used: bool = True
    message: str = ""
    resampled: int = 0
    carried: list[str] = field(default_factory=list)

    @property
    def particle_weights(self) -> np.ndarray:
        """Alias of ``weights``."""
        return self.weights




class MultiObjectTracker:
    """Coordinate particle filter over the joint pose of several rigid parts (see module docstring)."""

    def __init__(
        self,
        parts: list[PartSpec],
        intrinsics: Intrinsics,
        config: TrackerConfig | None = None,
        seed: int = 0,
    ) -> None:
        parts = list(parts)
        if not parts:
            raise ValueError("MultiObjectTracker needs at least one part (the object list is empty)")
        names = [p.name for p in parts]
        if len(set(names)) != len(names):
            raise ValueError(f"part names must be unique, got {names}")
        self.parts = parts
        self.names = names
        self.intrinsics = intrinsics
        self.config = config or TrackerConfig.preset("default")
        self.rng = np.random.default_rng(seed)
        self.likelihood = LikelihoodParams.from_config(self.config)
        k = len(parts)
        self.center = np.zeros((k, 3))
        self.half = np.zeros((k, 3))
        self.meshes: list[MeshModel | None] = []
        self.hulls: list[np.ndarray] = []
        self.corners: list[np.ndarray] = []
        for i, part in enumerate(parts):
            if part.box is not None:
                self.half[i] = np.asarray(part.box, np.float64) / 2.0
                self.meshes.append(None)
                self.hulls.append(part.vertices())
            else:
                model = MeshModel.from_part(part)
                self.meshes.append(model)
                self.center[i], self.half[i] = model.bounds()
                try:
                    import trimesh

                    hull = trimesh.Trimesh(model.vertices, model.faces).convex_hull.vertices
                except Exception:
                    hull = model.vertices
                self.hulls.append(np.asarray(hull, np.float64))
            signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
            self.corners.append(self.center[i] + signs * self.half[i])
        self.pairs = np.array([(a, b) for a in range(k) for b in range(a + 1, k)], np.int64).reshape(-1, 2)
        # the evaluated-pixel rectangles' part constants (tracker.filter.render): corners (K, 8, 3), body frame, and
        # |half| + |centre| (K,), m
        self._roi_corners = np.ascontiguousarray(np.stack(self.corners), np.float64)
        self._roi_radii = np.array([float(np.linalg.norm(self.half[i]) + np.linalg.norm(self.center[i]))
                                    for i in range(k)])
        self._penalty_shapes = weigh.penalty_shapes(self)  # the passes' penalty constants (filter/weigh.py)
        # downsampled pixel grid (full-resolution coordinates of the sampled pixels)
        f = self.config.downsample
        self._off = (f - 1) // 2
        self._us = np.arange(self._off, intrinsics.width, f)
        self._vs = np.arange(self._off, intrinsics.height, f)
        gj, gi = np.meshgrid(np.arange(self._vs.size), np.arange(self._us.size), indexing="ij")
        self._gi = gi.ravel().astype(np.int64)
        self._gj = gj.ravel().astype(np.int64)
        self._pu = self._us[self._gi].astype(np.float64)
        self._pv = self._vs[self._gj].astype(np.float64)
        self._rays = pixel_rays(intrinsics, self._pu, self._pv)
        self._hints: list[ResolvedConnection] = []
        self._color_targets: list = []
        self._surface: list[PartSurfaceModel | None] = [None] * k
        self._icp_last: list[tuple | None] = [None] * k  # (refined pose, blob centre, blob area, times reused)
        self._radius = [p.bounding_radius() if p.box is not None else float(np.linalg.norm(self.half[i]))
                        for i, p in enumerate(parts)]
        self._lattice = np.ones(k, np.int64)  # per part, the grid lattice its likelihood pixels were thinned to
        self._refiner = refine_stage.make_refiner(self) if self.config.dense_refinement else None
        self._initialized = False
        self._store: dict[str, np.ndarray] = {}
        self.estimates: dict[str, Pose] = {}
        self._warm_up()

    # ------------------------------------------------------------------ public API
    def initialize(self, poses: dict[str, Pose]) -> None:
        """Start every particle at the given camera-frame poses (all parts must be present), zero velocity."""
        missing = [n for n in self.names if n not in poses]
        if missing:
            raise ValueError(f"initial poses missing for part(s) {missing}")
        n, k = self.config.n_particles, len(self.parts)
        self.p = np.empty((n, k, 3))
        self.R = np.empty((n, k, 3, 3))
        for i, name in enumerate(self.names):
            pose = poses[name]
            self.p[:, i] = pose.t
            self.R[:, i] = pose.R
        self.v = np.zeros((n, k, 6))
        self.log_w = np.full(n, -np.log(n))
        # occlusion posterior per grid pixel and particle, stored pixel-major (P_grid, N) so that the evaluated
        # pixels' rows are gathered / written back contiguously
        self.occ = np.full((self._pu.size, n), self.config.initial_occlusion, np.float32)
        self.occ_time = np.full(self._pu.size, np.nan)
        self.estimates = {name: poses[name] for name in self.names}
        self.visibility = np.ones(k)
        self._noise_scale = np.ones(k)
        self._icp_last = [None] * k
        self._rest_t = np.array([poses[name].t for name in self.names], np.float64)  # rest-prior anchors
        self._rest_R = np.array([poses[name].R for name in self.names], np.float64)  # and their rotations
        self._rest_on = np.zeros(k, bool)
        self._blob_seen = np.zeros(k, bool)  # has the colour detector found the part's blob since initialize?
        self._support_on = np.zeros(k, bool)
        self._last_centers: dict[int, np.ndarray] = {}  # reliable blob centroids of the previous frame (px)
        self._carry = HandCarry(k, self.config, self.intrinsics, np.asarray(self._radius, np.float64))
        self.n_reseeded = 0  # re-seeding events since initialize (diagnostics, tests)
        self.n_reacquired = 0  # re-acquisition attempts since initialize (diagnostics, tests)
        self.silhouette_placed = np.zeros(k, bool)  # parts the table-silhouette stage placed this frame
        self.last_silhouette: list = [None] * k  # its fits this frame (diagnostics)
        self._loss = LossMonitor(k, self.config.loss_bad_frames)
        self._was_carried = np.zeros(k, bool)
        self._est_vel = np.zeros((k, 6))  # constant-velocity model: per-frame velocity estimate per part
        self._prev_poses: dict | None = None
        self._cooldown = np.zeros(k, np.int64)
        self._follow_blobs = None  # last frame's confident blobs (centroid, area[, outline]) per part, for blob follow
        self._blob_moved = np.zeros(k, bool)
        self._carry_moved = np.zeros(k, bool)  # parts the hand carry moved this frame (hidden_parts.follow_hands)
        self._carry_started = np.zeros(k, bool)  # of those, the parts whose carry started this frame
        self._pre_reseed: dict = {}  # part index -> estimate before this frame's re-seed at its blob (colour_input)
        self._pre_reseed_p: dict = {}  # part index -> its particles' positions (N, 3) before that re-seed
        self._blob_reappeared = np.zeros(k, bool)  # confident blob this frame but not in the last
        self._landmarks: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # scene motion: last frame's landmark poses
        self._scene_keyframes: dict = {}  # scene motion: unplaced part → (landmarks, its R, t) at its keyframe
        self._blob_uv_target: dict[int, np.ndarray] = {}  # carried parts: image position their blob says
        self._last_time: float | None = None
        self._quiet_memory = None  # quiet parts: last frame's blobs, estimate centres, small corrections
        self._quiet_skips = np.zeros(k, np.int64)  # passes skipped in a row per part
        self._quiet_now = np.zeros(k, bool)  # parts whose pass this frame skips
        self._settled = np.zeros(k, bool)  # quiet parts this frame (quiet_thin, quiet_refine_last; skipped or not)
        self.n_settled = 0  # part-frames found quiet since initialize (diagnostics, tests)
        self._held_poses: dict[int, Pose] = {}  # quiet parts' predicted mean poses this frame (quiet_refine_hold)
        self._quiet_faces: dict[int, np.ndarray] = {}  # box face sample points per part (quiet_max_residual_m)
        self.n_quiet_skipped = 0  # coordinate passes skipped since initialize (diagnostics, tests)
        self._initialized = True

    @property
    def landmark_poses(self) -> dict[str, Pose]:
        """This frame's well-seen resting parts (:func:`tracker.filter.scene_motion.landmarks`): name → camera-frame
        pose (the camera's pose from them: :mod:`tracker.odometry.part_landmarks`)."""
        return {self.names[i]: Pose.from_rt(R, t) for i, (R, t) in self._landmarks.items()}

    def set_connection_hints(self, hints: list) -> None:
        """Connections for Algorithm 6 (:class:`~tracker.filter.connection_hint.ConnectionHint`); [] clears them."""
        self._hints = resolve_hints(list(hints or []), self.names, self.config.n_particles,
                                    self.config.max_connection_fraction)

    def step(self, frame: Frame, detections: dict | None = None, table=None, occluders: np.ndarray | None = None,
             touched: Iterable[str] | None = None) -> TrackerState:  # fmt: skip
        """Process one frame; see the module docstring. ``detections``: name → object with ``.center``/``.score``;
        ``table``: object with ``.normal``/``.offset`` (or a ``(normal, offset)`` tuple) or None; ``occluders``:
        full-resolution bool H×W of pixels showing a known occluder such as a hand (occluder prior, see
        :class:`~tracker.filter.frame_context.FrameContext`) or None; ``touched``: names of the parts a tracked hand
        touches (a hidden one may then be carried, :mod:`~tracker.filter.hand_carry`).

        The stages, one module each: colour input (:mod:`~tracker.filter.colour_input`), hidden parts: hand carry
        and rest prior (:mod:`~tracker.filter.hidden_parts`), prediction (:mod:`~tracker.filter.predict`), evaluated
        pixels and rendering (:mod:`~tracker.filter.render`), the coordinate passes that weigh and resample
        (:mod:`~tracker.filter.weigh`), occlusion posterior and estimate (here), refinement and recovery
        (:mod:`~tracker.refine.refine_stage`)."""
        if not self._initialized:
            raise RuntimeError("MultiObjectTracker.step called before initialize(poses)")
        ctx = self._begin_frame(frame, table)
        ctx.occluders = occluders
        ctx.touched = frozenset(touched or ())
        self._blob_moved = blob_follow.follow_blobs(self, ctx, detections)
        u, detected = colour_input.control_inputs(self, ctx, detections)
        noise_scale = hidden_parts.hold_hidden_parts(self, ctx, detections, detected)
        pred = predict.deterministic(self, u)
        quiet_parts.quiet_parts(self, ctx, detections, detected, pred)  # parts whose pass is skipped: _quiet_now
        evaluated = render.evaluated_pixels(self, ctx.depth, self.p, self.R, pred[0], pred[1])
        ctx.timings["predict"] = (time.perf_counter() - ctx.t0) * 1e3
        if evaluated is None:
            return self._predict_only(frame, self.p, self.R, self.v, u, ctx.t0, ctx.timings,
                                      "no valid depth near the parts: update skipped, prediction kept")
        passes = weigh.coordinate_passes(self, ctx, u, noise_scale, detections, detected, evaluated, pred)
        self._finish_occlusion(ctx, passes)
        self.p, self.R, self.v, self.log_w = passes.p, passes.R, passes.v, passes.log_w
        self.last_log_likelihood = passes.ell  # penalised ℓ per particle of the last pass (diagnostics, tests)
        state = self._make_state(frame, ctx.t0, ctx.timings)
        state.resampled = passes.n_resampled
        hidden_parts.update_rest_anchors(self, detected)
        tg = time.perf_counter()
        refine_stage.refine(self, state, ctx.refine_depth, detections, ctx.table, ctx.depth)
        hidden_parts.upright_resting(self, state, ctx.table_plane)
        contact_align.align_contacts(self, state)
        hidden_parts.update_moving_anchors(self)
        scene_motion.follow_scene(self, state)
        ctx.timings["refine"] = (time.perf_counter() - tg) * 1e3
        predict.update_velocities(self, state.poses, detected & ~self._rest_on & ~self._carry.carried)
        if self.config.carry_follow:
            self._carry.record(ctx.now, np.array([state.poses[nm].t for nm in self.names]))
            if self.config.carry_backtrack > 0:
                # (a position-only refinement left the rotation unmeasured: not a pose for a carry to start from)
                placed = np.array([scene_motion.placed_by_depth(self, i) and not self._refiner.last[i].position_only
                                   for i in range(len(self.names))], bool)
                self._carry.note_placed(placed, np.array([state.poses[nm].R for nm in self.names]),
                                        np.array([state.poses[nm].t for nm in self.names]))
            state.carried = [nm for nm, c in zip(self.names, self._carry.carried, strict=True) if c]
        ctx.timings["total"] = (time.perf_counter() - ctx.t0) * 1e3
        state.timings = ctx.timings
        return state

    def _begin_frame(self, frame: Frame, table) -> FrameContext:
        intr = self.intrinsics
        if (frame.intrinsics.width, frame.intrinsics.height) != (intr.width, intr.height):
            raise ValueError(
                f"frame {frame.index}: image is {frame.intrinsics.width}x{frame.intrinsics.height} but the tracker "
                f"was built for {intr.width}x{intr.height}"
            )
        now = float(frame.timestamp)
        self._last_time = now
        self._blobs = {}  # this frame's blob masks by detection (the detection is kept alive)
        self._color_targets = []  # (part index, (u, v), weight) for the optional colour likelihood term
        return FrameContext(frame=frame, table=table, table_plane=table_normal_offset(table),
                            t0=time.perf_counter())

    def _finish_occlusion(self, ctx: FrameContext, passes: PassResult) -> None:
        """Occlusion posterior update (4.45) and each part's estimated visible fraction."""
        cfg = self.config
        tf = time.perf_counter()
        if cfg.use_occlusion_model:
            # the posterior goes straight into the stored rows of the evaluated pixels, in the particles' final order
            # (ancestors applied); grid pixels outside this frame's evaluated set keep their stored values without
            # re-indexing (no part can cover them this frame)
            vis_all = finish_occlusion_into(passes.Q, passes.F, passes.o_hat, passes.anc, len(self.parts), self.occ,
                                            passes.pix)
            self.occ_time[passes.pix] = ctx.now
            vis = normalize_log_weights(passes.log_w) @ vis_all
            self.visibility = vis
            if cfg.hidden_noise_scale < 1.0:
                self._noise_scale = np.clip(vis / cfg.visible_fraction_full, cfg.hidden_noise_scale, 1.0)
        ctx.timings["occlusion"] = (time.perf_counter() - tf) * 1e3

    # ------------------------------------------------------------------ internals
    def _buffer(self, name: str, shape: tuple[int, int], dtype, fill=None) -> np.ndarray:
        """A C-contiguous work array of ``shape`` backed by persistent storage (grown when needed), optionally
        filled. Reusing the storage avoids fresh page-faulting allocations of several MB per frame and pass."""
        size = int(shape[0]) * int(shape[1])
        store = self._store.get(name)
        if store is None or store.size < size or store.dtype != np.dtype(dtype):
            store = np.empty(max(size, 1) * 5 // 4 + 64, dtype)
            self._store[name] = store
        out = store[:size].reshape(shape)
        if fill is not None:
            out.fill(fill)
        return out

    def _predict_only(self, frame, p_prev, R_prev, v_prev, u, t0, timings, message) -> TrackerState:
        cfg = self.config
        n, k = cfg.n_particles, len(self.parts)
        p = np.empty_like(p_prev)
        R = np.empty_like(R_prev)
        v = np.empty_like(v_prev)
        for i in range(k):
            noise = sample_noise(self.rng, n, cfg.sigma_v, cfg.sigma_w, cfg.wide_noise_fraction, cfg.wide_noise_scale)
            p[:, i], R[:, i], v[:, i] = propagate(p_prev[:, i], R_prev[:, i], v_prev[:, i], u[i], noise,
                                                  predict.velocity_gain(cfg), cfg.b)
        self.p, self.R, self.v = p, R, v
        state = self._make_state(frame, t0, timings)
        state.depth_used = False
        state.message = message
        timings["total"] = (time.perf_counter() - t0) * 1e3
        state.timings = timings
        return state

    def _make_state(self, frame, t0, timings) -> TrackerState:
        w = normalize_log_weights(self.log_w)
        poses = dict(zip(self.names, mean_poses(self.p, self.R, w), strict=True))
        particles = {name: self.p[:, i].astype(np.float32) for i, name in enumerate(self.names)}
        self.estimates = poses
        return TrackerState(frame.index, float(frame.timestamp), poses, particles, w, timings)

    def _warm_up(self) -> None:
        """Compile (or load from cache) the numba kernels on tiny inputs."""
        n, k, p = 2, len(self.parts), 4
        R = np.tile(np.eye(3), (n, k, 1, 1))
        t = np.zeros((n, k, 3))
        t[..., 2] = 0.5
        rays = self._rays[:p]
        D = np.full((n, k * p), np.inf, np.float32)
        loc = np.arange(k * p, dtype=np.int64).reshape(k, p)
        dirty = np.zeros((n, p), np.uint8)
        idx = np.arange(n, dtype=np.int64)
        sub = np.arange(p, dtype=np.int64)
        for i in range(k):
            render.render(self, i, t, R, idx, rays, self._pu[:p], self._pv[:p], self._gi[:p], self._gj[:p], sub, D, loc,
                         dirty)
        z = np.full(p, 0.5)
        s, e, lp = pixel_constants(z, self.likelihood)
        oh = np.zeros((n, p), np.float32)
        C = np.zeros((n, p), np.float32)
        Q = np.full((n, p), -1.0, np.float32)
        F = np.full((n, p), -1, np.int8)
        an = np.arange(n)
        ell = np.zeros(n)
        cm = np.ones((k, p), np.uint8)
        cv = np.ones(k, np.uint8)
        update_log_likelihood(D, loc, sub, z, s, e, lp, oh, an, C, Q, F, ell, 0.01, 0.69, 0.001, True, dirty, 1.0, cm,
                              cv)
        finish_occlusion(Q, F, oh, an, k)
        if len(self.pairs):
            intersection_log_penalty(R, t, self.center, self.half, self.pairs, 0.001, 0.01)
        # kernels first called only once a part rests hidden or a hand carries one (else loaded mid-session)
        hidden_parts.warm_up()
        hand_carry.warm_up()

