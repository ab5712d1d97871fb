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
4. occlusion posterior update (4.45) and the estimate (weighted mean position, rotation mean).

All-NaN depth (or no evaluated pixel): the update is skipped, the prediction kept, and the returned state says
so (``depth_used`` False, ``message``). Use :class:`MultiObjectTracker` as::

    tracker = MultiObjectTracker(parts, intrinsics, TrackerConfig.preset("default"), seed=0)
    tracker.initialize(first_poses)
    state = tracker.step(frame, detections, table)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tracker.filter.connection_particles import ResolvedConnection, apply_connections, resolve_hints
from tracker.filter.depth_likelihood import (
    LikelihoodParams,
    finish_occlusion,
    pixel_constants,
    predict_occlusion_rows,
    update_log_likelihood,
)
from tracker.filter.hand_carry import HandCarry, supported_by_other
from tracker.filter.motion_model import color_input, mean_pose, propagate, sample_noise
from tracker.filter.penalties import intersection_flags, intersection_log_penalty, lowest_heights, table_log_penalty
from tracker.filter.resampling import kl_from_uniform, normalize_log_weights, systematic_resample, take_rows
from tracker.filter.tracker_config import TrackerConfig
from tracker.frame import Frame
from tracker.geometry.box_renderer import pixel_rays, render_boxes_at_pixels
from tracker.geometry.camera import Intrinsics
from tracker.geometry.mesh_renderer import MeshModel, render_mesh_at_pixels
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.refine.dense_depth import RefineSettings
from tracker.refine.icp_refinement import PartSurfaceModel, icp_refine, part_points
from tracker.refine.part_refiner import PartRefiner
from tracker.refine.recovery import CUBE_STARTS, MESH_STARTS, LossMonitor, reacquire


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


def _table_normal_offset(table) -> tuple[np.ndarray, float] | None:
    """(normal, offset) of a TablePlane-like object or a ``(normal, offset)`` tuple; None when absent."""
    if table is None:
        return None
    if hasattr(table, "normal") and hasattr(table, "offset"):
        n, off = table.normal, table.offset
    else:
        n, off = table
    n = np.asarray(n, np.float64).reshape(3)
    norm = np.linalg.norm(n)
    if not np.isfinite(norm) or norm < 1e-9:
        raise ValueError("table plane normal must be a non-zero finite vector")
    return n / norm, float(off) / norm


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
        self._refiner = self._make_refiner() if self.config.dense_refinement else None
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
        self._rest_on = np.zeros(k, bool)
        self._blob_seen = np.zeros(k, bool)  # has the colour detector found the part's blob since initialize?
        self._support_on = np.zeros(k, bool)
        self._last_centers: dict[int, np.ndarray] = {}  # reliable blob centroids of the previous frame (px)
        self._carry = HandCarry(k, self.config, self.intrinsics, np.asarray(self._radius, np.float64))
        self.n_reseeded = 0  # re-seeding events since initialize (diagnostics, tests)
        self.n_reacquired = 0  # re-acquisition attempts since initialize (diagnostics, tests)
        self._loss = LossMonitor(k, self.config.loss_bad_frames)
        self._was_carried = np.zeros(k, bool)
        self._cooldown = np.zeros(k, np.int64)
        self._last_time: float | None = None
        self._initialized = True

    def set_connection_hints(self, hints: list) -> None:
        """Connections for Algorithm 6 (:class:`~tracker.filter.connection_hint.ConnectionHint`); [] clears them."""
        self._hints = resolve_hints(list(hints or []), self.names, self.config.n_particles,
                                    self.config.max_connection_fraction)

    def step(self, frame: Frame, detections: dict | None = None, table=None) -> TrackerState:
        """Process one frame; see the module docstring. ``detections``: name → object with ``.center``/``.score``;
        ``table``: object with ``.normal``/``.offset`` (or a ``(normal, offset)`` tuple) or None."""
        if not self._initialized:
            raise RuntimeError("MultiObjectTracker.step called before initialize(poses)")
        t0 = time.perf_counter()
        cfg = self.config
        intr = self.intrinsics
        if (frame.intrinsics.width, frame.intrinsics.height) != (intr.width, intr.height):
            raise ValueError(
                f"frame {frame.index}: image is {frame.intrinsics.width}x{frame.intrinsics.height} but the tracker "
                f"was built for {intr.width}x{intr.height}"
            )
        now = float(frame.timestamp)
        self._last_time = now
        self._blobs: dict[int, tuple] = {}  # this frame's blob masks by detection (the detection is kept alive)
        table_plane = _table_normal_offset(table)
        plane = table_plane if cfg.use_table_penalty else None
        support_plane = table_plane if cfg.support_prior_sigma > 0 else None
        timings: dict[str, float] = {}
        n, k = cfg.n_particles, len(self.parts)

        # 1. colour input (and re-seeding of parts whose reliable colour blob lies off their estimate)
        depth = frame.depth
        u = np.zeros((k, 3))
        self._color_targets = []  # (part index, (u, v), weight) for the optional colour likelihood term
        detected = np.zeros(k, bool)
        if cfg.use_color_input and detections:
            for i, name in enumerate(self.names):
                det = detections.get(name)
                if det is None:
                    continue
                score = float(getattr(det, "score", 0.0) or 0.0)
                center = getattr(det, "center", None)
                if center is None or score < cfg.min_detection_score:
                    continue
                area = getattr(det, "area", None)
                reliable = (score >= cfg.reseed_min_score and area is not None and np.isfinite(area)
                            and area >= cfg.reseed_min_area_px
                            and self._area_ratio(i, area) >= cfg.reseed_min_area_ratio)
                detected[i] = reliable
                hit = self._surface_depth(i, center)
                off_silhouette = reliable and not np.isfinite(hit)
                if cfg.color_area_weighting and not off_silhouette:
                    score *= self._area_ratio(i, area)
                if off_silhouette and cfg.reseed_fraction > 0 and depth is not None:
                    self._reseed(i, det, depth)
                    hit = self._surface_depth(i, center)
                if cfg.color_likelihood_px > 0:
                    # with a dead zone the term tolerates the centroid bias of a partly hidden blob: full score
                    wgt = min(float(det.score) if cfg.color_term_dead_zone > 0 else score, 1.0)
                    self._color_targets.append((i, np.asarray(center, np.float64), wgt))
                est = self.estimates[name]
                offset = float(est.t[2] - hit) if np.isfinite(hit) else self._surface_fallback(i)
                blob = self._blob_mask(det, depth.shape) if depth is not None and cfg.color_mask_likelihood else None
                u[i] = color_input(center, min(score, 1.0), est, depth, intr, cfg.lambda_z, cfg.depth_radius_px,
                                   offset, mask=blob)
        if cfg.carry_follow:
            self._follow_hands(depth, detected, table_plane, detections)
        noise_scale = self._noise_scale.copy()
        self._rest_on = np.zeros(k, bool)
        if cfg.rest_prior_sigma > 0 and cfg.use_color_input and detections is not None:
            # little depth evidence (hidden, or in the sensor's shadow next to a hand) and no sign of motion
            self._rest_on = self.visibility < cfg.rest_prior_max_visibility
            for i in np.nonzero(self._rest_on)[0]:
                if self._blob_left_rest(i, detections.get(self.names[i])):
                    self._rest_on[i] = False  # a sliver of the part shows where it was not: it is moving
            if self._rest_on.any():
                self.v[:, self._rest_on] = 0.0
        if cfg.detected_full_noise:
            noise_scale[detected] = 1.0

        # 2. deterministic prediction and evaluated pixels
        p_prev, R_prev, v_prev = self.p, self.R, self.v
        p_cur = np.empty_like(p_prev)
        R_cur = np.empty_like(R_prev)
        v_cur = np.empty_like(v_prev)
        zero = np.zeros((n, 6))
        for i in range(k):
            p_cur[:, i], R_cur[:, i], v_cur[:, i] = propagate(p_prev[:, i], R_prev[:, i], v_prev[:, i], u[i], zero,
                                                              cfg.k_v, cfg.b)
        evaluated = self._evaluated_pixels(depth, p_prev, R_prev, p_cur, R_cur)
        timings["predict"] = (time.perf_counter() - t0) * 1e3
        if evaluated is None:
            return self._predict_only(frame, p_prev, R_prev, v_prev, u, t0, timings,
                                      "no valid depth near the parts: update skipped, prediction kept")
        pix, regions = evaluated
        loc = np.full(regions.shape, -1, np.int64)
        loc[regions] = np.arange(int(regions.sum()), dtype=np.int64)  # one depth column per (part, pixel)
        z = depth.reshape(-1)[self._vs[self._gj[pix]] * intr.width + self._us[self._gi[pix]]].astype(np.float64)
        s, e, log_po_inf = pixel_constants(z, self.likelihood)
        rays, pu, pv = self._rays[pix], self._pu[pix], self._pv[pix]
        gi, gj = self._gi[pix], self._gj[pix]
        npix = pix.size
        if cfg.use_occlusion_model:
            last = self.occ_time[pix]
            dtp = np.where(np.isfinite(last), now - last, 0.0)
            o_hat = np.ascontiguousarray(predict_occlusion_rows(self.occ[pix], dtp, cfg.p_occ_given_vis,
                                                                cfg.p_occ_given_occ).T)
        else:
            o_hat = np.zeros((n, npix), np.float32)

        # full render + likelihood at the deterministic prediction
        t1 = time.perf_counter()
        m_cols = int(regions.sum())
        D = self._buffer("D0", (n, m_cols), np.float32, np.inf)
        dirty = self._buffer("dirty", (n, npix), np.uint8, 0)
        all_particles = np.arange(n, dtype=np.int64)
        all_pix = np.arange(npix, dtype=np.int64)
        if k > 1:  # with one part, its own pass below renders it everywhere it can be: no render needed here
            for i in range(k):
                self._render(i, p_cur, R_cur, all_particles, rays, pu, pv, gi, gj, all_pix, D, loc, dirty)
        t2 = time.perf_counter()
        C = self._buffer("C0", (n, npix), np.float32, 0.0)
        Q = self._buffer("Q0", (n, npix), np.float32, -1.0)  # consistent with D = inf: nothing covered yet
        F = self._buffer("F0", (n, npix), np.int8, -1)
        spare = {"D": "D1", "C": "C1", "Q": "Q1", "F": "F1"}  # double buffers for resampling without allocation
        ell = np.zeros(n)
        anc = np.arange(n)
        prm = self.likelihood
        beta, lam, tail = prm.tail_weight, prm.occluder_rate, prm.tail_weight / prm.max_depth
        use_occ = bool(cfg.use_occlusion_model)
        alpha = float(cfg.likelihood_exponent)
        cmask, cvalid = self._color_masks(detections, gi, gj)
        occ_cap = float(cfg.occluded_evidence_cap)
        update_log_likelihood(D, loc, all_pix, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta, lam, tail, use_occ,
                              dirty, alpha, cmask, cvalid, occ_cap)
        t_render = t2 - t1
        t_lik = time.perf_counter() - t2
        t_res = 0.0
        t_pen = 0.0
        ell_prev = np.zeros(n)  # ℓ_0 = 0 at the start of each frame
        log_w = self.log_w.copy()
        n_resampled = 0

        # 3. coordinate passes (Algorithm 5); unlocked hints move only parts estimated visible enough
        forceable = self.visibility >= cfg.hint_min_visibility  # previous frame's occlusion estimate
        if cfg.hint_min_visibility > 0 and cfg.use_color_input and detections:
            forceable &= detected  # and a reliable colour blob now: the hand may have covered the part this frame
        for i in range(k):
            old_p, old_R = p_cur[:, i].copy(), R_cur[:, i].copy()
            scale = noise_scale[i]
            noise = sample_noise(self.rng, n, cfg.sigma_v * scale, cfg.sigma_w * scale, cfg.wide_noise_fraction,
                                 cfg.wide_noise_scale)
            p_cur[:, i], R_cur[:, i], v_cur[:, i] = propagate(p_prev[:, i], R_prev[:, i], v_prev[:, i], u[i], noise,
                                                              cfg.k_v, cfg.b)
            changed_objs = {i}
            forced = None
            if self._hints and cfg.use_connection_particles:
                before_p = p_cur.copy()
                before_R = R_cur.copy()
                forced = apply_connections(p_cur, R_cur, self._hints, forceable)
                forced[:, i] = False
                for o in range(k):
                    if forced[:, o].any():
                        changed_objs.add(o)
            # pixels whose depth may change: old and new projections of every changed part
            rect = self._bbox(i, old_p, old_R)
            rect = _union(rect, self._bbox(i, p_cur[:, i], R_cur[:, i]))
            for o in changed_objs - {i}:
                sel = forced[:, o]
                rect = _union(rect, self._bbox(o, before_p[sel, o], before_R[sel, o]))
                rect = _union(rect, self._bbox(o, p_cur[sel, o], R_cur[sel, o]))
            subset = np.nonzero((pu >= rect[0]) & (pu <= rect[1]) & (pv >= rect[2]) & (pv <= rect[3]))[0]
            ta = time.perf_counter()
            self._render(i, p_cur, R_cur, all_particles, rays, pu, pv, gi, gj, subset, D, loc, dirty)
            for o in changed_objs - {i}:
                self._render(o, p_cur, R_cur, np.nonzero(forced[:, o])[0].astype(np.int64), rays, pu, pv, gi, gj,
                             subset, D, loc, dirty)
            tb = time.perf_counter()
            update_log_likelihood(D, loc, subset.astype(np.int64), z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta,
                                  lam, tail, use_occ, dirty, alpha, cmask, cvalid, occ_cap)
            tc = time.perf_counter()
            ell_tot = (ell + self._log_penalties(p_cur, R_cur, plane) + self._log_rest_prior(p_cur)
                       + self._log_support_prior(p_cur, R_cur, support_plane))
            td = time.perf_counter()
            log_w += ell_tot - ell_prev
            ell_prev = ell_tot
            w = normalize_log_weights(log_w)
            log_w = np.log(np.maximum(w, 1e-300))
            if kl_from_uniform(w) > cfg.kl_max:
                idx = systematic_resample(w, self.rng)
                p_prev, R_prev, v_prev = p_prev[idx], R_prev[idx], v_prev[idx]
                p_cur, R_cur, v_cur = p_cur[idx], R_cur[idx], v_cur[idx]
                # dirty flags are all clear; ô is reached through anc
                D, C, Q, F = (self._take(spare, key, arr, idx) for key, arr in (("D", D), ("C", C), ("Q", Q), ("F", F)))
                ell, ell_prev, anc = ell[idx], ell_prev[idx], anc[idx]
                log_w = np.full(n, -np.log(n))
                n_resampled += 1
            te = time.perf_counter()
            t_render += tb - ta
            t_lik += tc - tb
            t_pen += td - tc
            t_res += te - td

        # 4. occlusion posterior and estimate
        tf = time.perf_counter()
        if use_occ:
            post, vis_all = finish_occlusion(Q, F, o_hat, anc, k)
            # post is already in the particles' final order (ancestors applied); grid pixels outside this frame's
            # evaluated set keep their stored values without re-indexing (no part can cover them this frame)
            self.occ[pix] = post.T
            self.occ_time[pix] = now
            vis = normalize_log_weights(log_w) @ vis_all
            self.visibility = vis
            if cfg.hidden_noise_scale < 1.0:
                self._noise_scale = np.clip(vis / cfg.visible_fraction_full, cfg.hidden_noise_scale, 1.0)
        t_occ = time.perf_counter() - tf
        self.p, self.R, self.v, self.log_w = p_cur, R_cur, v_cur, log_w
        self.last_log_likelihood = ell_prev  # penalised ℓ per particle of the last pass (diagnostics, tests)
        state = self._make_state(frame, t0, timings)
        if cfg.rest_prior_sigma > 0:
            well = detected & (self.visibility >= cfg.visible_fraction_full)
            for i in np.nonzero(well)[0]:
                self._rest_t[i] = self.estimates[self.names[i]].t
        state.resampled = n_resampled
        tg = time.perf_counter()
        if cfg.dense_refinement and depth is not None:
            self._dense_refine(state, depth, detections)
        elif cfg.icp_refinement:
            self._refine(state, depth, detections, table)
        t_icp = time.perf_counter() - tg
        if cfg.carry_follow:
            self._carry.record(now, np.array([state.poses[nm].t for nm in self.names]))
            state.carried = [nm for nm, c in zip(self.names, self._carry.carried, strict=True) if c]
        timings.update(render=t_render * 1e3, likelihood=t_lik * 1e3, penalties=t_pen * 1e3,
                       resample=t_res * 1e3, occlusion=t_occ * 1e3, icp=t_icp * 1e3)
        timings["total"] = (time.perf_counter() - t0) * 1e3
        state.timings = timings
        return state

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

    def _take(self, spare: dict, key: str, arr: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """``arr[idx]`` (rows) written into the spare buffer of ``key``; the old array becomes the spare."""
        name = spare[key]
        out = self._buffer(name, arr.shape, arr.dtype)
        take_rows(arr, idx, out)
        spare[key] = name[:-1] + ("0" if name.endswith("1") else "1")
        return out

    def _predict_only(self, frame, p_prev, R_prev, v_prev, u, t0, timings, message) -> TrackerState:
        cfg = self.config
        n, k = cfg.n_particles, len(self.parts)
        p = np.empty_like(p_prev)
        R = np.empty_like(R_prev)
        v = np.empty_like(v_prev)
        for i in range(k):
            noise = sample_noise(self.rng, n, cfg.sigma_v, cfg.sigma_w, cfg.wide_noise_fraction, cfg.wide_noise_scale)
            p[:, i], R[:, i], v[:, i] = propagate(p_prev[:, i], R_prev[:, i], v_prev[:, i], u[i], noise, cfg.k_v, cfg.b)
        self.p, self.R, self.v = p, R, v
        state = self._make_state(frame, t0, timings)
        state.depth_used = False
        state.message = message
        timings["total"] = (time.perf_counter() - t0) * 1e3
        state.timings = timings
        return state

    def _make_state(self, frame, t0, timings) -> TrackerState:
        w = normalize_log_weights(self.log_w)
        poses = {}
        particles = {}
        for i, name in enumerate(self.names):
            poses[name] = mean_pose(self.p[:, i], self.R[:, i], w)
            particles[name] = self.p[:, i].astype(np.float32)
        self.estimates = poses
        return TrackerState(frame.index, float(frame.timestamp), poses, particles, w, timings)

    def _render(self, obj, p, R, particles, rays, pu, pv, gi, gj, subset, D, loc, dirty) -> None:
        if particles.size == 0 or subset.size == 0:
            return
        intr = self.intrinsics
        mesh = self.meshes[obj]
        if mesh is None:
            render_boxes_at_pixels(R, p, self.center, self.half, obj, particles, rays, pu, pv, subset,
                                   intr.fx, intr.fy, intr.cx, intr.cy, D, loc, dirty)
        else:
            render_mesh_at_pixels(R, p, mesh.vertices, mesh.faces, obj, particles, gi, gj, subset,
                                  float(self.config.downsample), float(self._off), intr.fx, intr.fy, intr.cx,
                                  intr.cy, D, loc, dirty)

    def _log_penalties(self, p, R, plane) -> np.ndarray:
        cfg = self.config
        out = np.zeros(p.shape[0])
        if self._color_targets:
            intr = self.intrinsics
            sig2 = cfg.color_likelihood_px**2
            for i, c, wgt in self._color_targets:
                ctr = np.einsum("nij,j->ni", R[:, i], self.center[i]) + p[:, i]
                z = np.maximum(ctr[:, 2], 1e-3)
                du = intr.fx * ctr[:, 0] / z + intr.cx - c[0]
                dv = intr.fy * ctr[:, 1] / z + intr.cy - c[1]
                d2 = du * du + dv * dv
                if cfg.color_term_dead_zone > 0:
                    r_in = cfg.color_term_dead_zone * float(self.half[i].min()) * intr.fx / z
                    d2 = np.maximum(np.sqrt(d2) - r_in, 0.0) ** 2
                out -= 0.5 * wgt * np.minimum(d2, 9.0 * sig2) / sig2
        if cfg.use_intersection_penalty and len(self.pairs):
            out += intersection_log_penalty(R, p, self.center, self.half, self.pairs, cfg.contact_tolerance,
                                            cfg.lambda_i)
        if plane is not None and cfg.lambda_h > 0:
            hmin = lowest_heights(R, p, self.hulls, plane[0], plane[1])
            out += table_log_penalty(hmin, cfg.lambda_h, cfg.table_tolerance)
        return out

    def _follow_hands(self, depth, detected: np.ndarray, plane, detections) -> None:
        """Hand carry (:mod:`tracker.filter.hand_carry`): shift hidden carried parts with the hand that holds them
        (``plane``: the table's (normal, offset) or None). A carried part whose reliable colour blob stays put while
        the hand moves on has been let go: released."""
        cfg = self.config
        k = len(self.parts)
        pos = np.array([self.estimates[nm].t for nm in self.names])
        heights = np.full(k, np.inf)
        if plane is not None:
            for i, nm in enumerate(self.names):
                heights[i] = self._lowest_height(i, self.estimates[nm].R, pos[i], plane)
        hidden = self.visibility < cfg.rest_prior_max_visibility  # little depth evidence (previous frame)
        delta = self._carry.update(depth, pos, hidden, ~hidden, heights, plane)
        centers = {}
        for i, nm in enumerate(self.names):
            det = detections.get(nm) if detections else None
            c = getattr(det, "center", None) if det is not None else None
            if c is not None and detected[i]:
                centers[i] = np.asarray(c, np.float64)
        for i in np.nonzero(np.abs(delta).sum(1) > 0)[0]:
            nm = self.names[i]
            if i in centers and i in self._last_centers:
                uv = self.intrinsics.project(np.array([pos[i], pos[i] + delta[i]]))
                hand_px = float(np.linalg.norm(uv[1] - uv[0]))
                blob_px = float(np.linalg.norm(centers[i] - self._last_centers[i]))
                if hand_px > 3.0 and blob_px < 0.3 * hand_px:
                    self._carry.release(i)
                    continue
            self.p[:, i] += delta[i]
            self.v[:, i] = 0.0
            est = self.estimates[nm]
            self.estimates[nm] = Pose.from_rt(est.R, est.t + delta[i])
            self._rest_t[i] = self._rest_t[i] + delta[i]
        self._last_centers = centers
        self._update_support(hidden & ~self._carry.carried, pos, heights, plane)

    def _update_support(self, unseen: np.ndarray, pos: np.ndarray, heights: np.ndarray, plane) -> None:
        """Which parts get the support prior: ``unseen`` (little depth evidence, not carried) and not on another
        part. Their rest anchors, when in the air (last seen in a hand), are set down on the table too."""
        k = len(self.parts)
        self._support_on = np.zeros(k, bool)
        if plane is None or self.config.support_prior_sigma <= 0:
            return
        for i in np.nonzero(unseen)[0]:
            if supported_by_other(i, pos, heights, self._carry.radii, margin=0.01):
                continue
            self._support_on[i] = True
            h = self._lowest_height(i, self.estimates[self.names[i]].R, self._rest_t[i], plane)
            if h > self.config.carry_min_height:
                self._rest_t[i] = self._rest_t[i] - h * plane[0]

    def _lowest_height(self, obj: int, R: np.ndarray, t: np.ndarray, plane) -> float:
        """Height (m) above the table plane ``(n, d)`` of part ``obj``'s lowest vertex at pose (R, t)."""
        n, d = plane
        return float((self.hulls[obj] @ (R.T @ n)).min() + t @ n + d)

    def _blob_left_rest(self, obj: int, det) -> bool:
        """Does the colour blob of part ``obj`` reach more than ``rest_release_px`` beyond the part's projected
        bounding rectangle at its rest anchor? (A resting part partly hidden by a hand shows a blob inside it.)"""
        bbox = getattr(det, "bbox", None) if det is not None else None
        if bbox is None or getattr(det, "center", None) is None or self.config.rest_release_px <= 0:
            return False
        est = self.estimates[self.names[obj]]
        pts = self.corners[obj] @ est.R.T + self._rest_t[obj]
        if np.any(pts[:, 2] < 0.01):
            return False
        uv = self.intrinsics.project(pts)
        x, y, w, h = (float(v) for v in bbox)
        m = self.config.rest_release_px
        return bool(x < uv[:, 0].min() - m or x + w > uv[:, 0].max() + m or y < uv[:, 1].min() - m
                    or y + h > uv[:, 1].max() + m)

    def _log_support_prior(self, p, R, plane) -> np.ndarray | float:
        """Support prior (TrackerConfig.support_prior_sigma): the lowest point of an unseen, unheld part that is not
        on another part lies on the table; quadratic within 3σ, linear beyond (it still pulls a floating part)."""
        if plane is None or not self._support_on.any():
            return 0.0
        sig = self.config.support_prior_sigma
        out = np.zeros(p.shape[0])
        n, d = plane
        for i in np.nonzero(self._support_on)[0]:
            nb = np.einsum("nji,j->ni", R[:, i], n)  # Rᵀ n per particle
            h = np.abs((nb @ self.hulls[i].T).min(axis=1) + p[:, i] @ n + d) / sig
            out -= np.where(h < 3.0, 0.5 * h * h, 3.0 * h - 4.5)
        return out

    def _log_rest_prior(self, p) -> np.ndarray | float:
        """Rest prior (TrackerConfig.rest_prior_sigma): Gaussian pull of resting hidden parts to their anchors."""
        if not self._rest_on.any():
            return 0.0
        sig2 = self.config.rest_prior_sigma ** 2
        d2 = ((p[:, self._rest_on] - self._rest_t[self._rest_on]) ** 2).sum(-1)
        return -0.5 * np.minimum(d2, 9.0 * sig2).sum(-1) / sig2

    def _bbox(self, obj, p, R) -> tuple[float, float, float, float]:
        """Full-resolution pixel rectangle (umin, umax, vmin, vmax) covering part ``obj`` for all given poses."""
        if p.shape[0] == 0:
            return (np.inf, -np.inf, np.inf, -np.inf)
        pts = np.einsum("nij,cj->nci", R, self.corners[obj]) + p[:, None, :]
        zc = pts[..., 2]
        if np.any(zc < 0.01):
            return (-np.inf, np.inf, -np.inf, np.inf)
        intr = self.intrinsics
        u = intr.fx * pts[..., 0] / zc + intr.cx
        v = intr.fy * pts[..., 1] / zc + intr.cy
        m = 1.0
        return (u.min() - m, u.max() + m, v.min() - m, v.max() + m)

    def _evaluated_pixels(self, depth, p_prev, R_prev, p_det, R_det):
        """Valid pixels near the parts: (indices into the downsampled grid (P,), per-part region masks (K, P)),
        or None when there are none. A part's region is its projected rectangle over all particles (previous and
        predicted poses) widened by the margin and the motion-noise spread (the mixture's std, 3σ)."""
        if depth is None:
            return None
        cfg = self.config
        intr = self.intrinsics
        z = depth[np.ix_(self._vs, self._us)].reshape(-1)
        valid = np.isfinite(z) & (z > 0) & (z < cfg.max_depth)
        if not valid.any():
            return None
        k = len(self.parts)
        regions = np.zeros((k, z.size), bool)
        f = cfg.wide_noise_fraction
        spread = np.sqrt((1.0 - f) + f * cfg.wide_noise_scale**2)
        for i in range(k):
            rect = _union(self._bbox(i, p_prev[:, i], R_prev[:, i]), self._bbox(i, p_det[:, i], R_det[:, i]))
            zc = max(float(np.median(p_det[:, i, 2])), 0.05)
            radius = float(np.linalg.norm(self.half[i]) + np.linalg.norm(self.center[i]))
            scale = spread * self._noise_scale[i]
            margin = (cfg.roi_margin_px * cfg.downsample
                      + 3.0 * scale * (cfg.sigma_v + cfg.sigma_w * radius) * intr.fx / zc)
            regions[i] = ((self._pu >= rect[0] - margin) & (self._pu <= rect[1] + margin)
                          & (self._pv >= rect[2] - margin) & (self._pv <= rect[3] + margin))
        budget = cfg.likelihood_pixels_per_part
        if budget > 0:
            # a part that covers many grid pixels (a large mesh, a part close to the camera) is evaluated on an even
            # subset of at most ``budget`` of them: the likelihood's cost stays bounded, the refinement after the
            # filter restores the precision
            keep = np.zeros(z.size, bool)
            for i in range(k):
                idx = np.nonzero(regions[i] & valid)[0]
                step = -(-idx.size // budget)
                keep[idx[::step] if step > 1 else idx] = True
        else:
            keep = regions.any(axis=0) & valid
        pix = np.nonzero(keep)[0].astype(np.int64)
        if not pix.size:
            return None
        return pix, regions[:, pix]

    def _refine(self, state: TrackerState, depth, detections, table) -> None:
        """ICP refinement of well-visible parts (see :mod:`tracker.refine.icp_refinement`); shifts their particles."""
        cfg = self.config
        plane = _table_normal_offset(table)
        for i, name in enumerate(self.names):
            if self.visibility[i] < cfg.icp_min_visibility:
                continue
            det = detections.get(name) if detections else None
            coloured = self.parts[i].color is not None and bool(detections)
            est = state.poses[name]
            ref = self._reuse_icp(i, est, det) if coloured else None
            fresh = ref is None
            if fresh:
                blob = None
                if coloured:
                    blob = self._blob_mask(det, depth.shape)
                    if blob is None:  # a coloured part that is not detected now: do not trust nearby points
                        self._icp_last[i] = None
                        continue
                if self._surface[i] is None:
                    self._surface[i] = PartSurfaceModel(self.parts[i])
                others = np.array([state.poses[n].t for n in self.names if n != name]).reshape(-1, 3)
                pts = part_points(depth, self.intrinsics, est, self._radius[i] + 0.005, blob, plane, cfg.icp_stride,
                                  others=others)
                ref = icp_refine(self._surface[i], pts, est, cfg.icp_iterations)
                self._icp_last[i] = None
                if ref is None:
                    continue
            Rd = ref.R @ est.R.T
            angle = float(np.arccos(np.clip((np.trace(Rd) - 1.0) / 2.0, -1.0, 1.0)))
            if np.linalg.norm(ref.t - est.t) > cfg.icp_max_translation or angle > cfg.icp_max_rotation:
                self._icp_last[i] = None
                continue
            if self._intersects_others(i, ref, state.poses):
                self._icp_last[i] = None
                continue
            if fresh and det is not None and getattr(det, "center", None) is not None:
                self._icp_last[i] = (ref, np.asarray(det.center, np.float64), float(getattr(det, "area", 0) or 0), 0)
            self.p[:, i] = (self.p[:, i] - est.t) @ Rd.T + ref.t
            self.R[:, i] = Rd @ self.R[:, i]
            state.poses[name] = ref
            state.particles[name] = self.p[:, i].astype(np.float32)
            self.estimates[name] = ref

    def _make_refiner(self) -> PartRefiner:
        cfg = self.config
        shapes = []
        for i in range(len(self.parts)):
            mesh = self.meshes[i]
            if mesh is None:
                shapes.append(("box", self.center[i].copy(), self.half[i].copy()))
            else:
                shapes.append(("mesh", np.ascontiguousarray(mesh.vertices, np.float64),
                               np.ascontiguousarray(mesh.faces, np.int64)))
        settings = RefineSettings(
            thresholds=tuple(cfg.refine_thresholds), updates_per_iteration=cfg.refine_updates,
            occlusion_m=cfg.refine_occlusion, lambda_rot=cfg.refine_lambda_rot, lambda_trans=cfg.refine_lambda_trans,
            min_valid_fraction=cfg.refine_min_valid_fraction, max_points=cfg.refine_max_points,
        )
        return PartRefiner(self.intrinsics, shapes, list(self.center), self.corners, settings, cfg.refine_stride,
                           cfg.refine_max_translation, cfg.refine_max_rotation)

    def _dense_refine(self, state: TrackerState, depth: np.ndarray, detections) -> None:
        """Dense-depth refinement of every visible part (:mod:`tracker.refine.part_refiner`) and re-acquisition of
        lost or just released parts (:mod:`tracker.refine.recovery`); the particles move with each accepted
        correction. A coloured part is refined only on the pixels of its colour blob (hands and other parts left out)
        and not at all while its blob is missing."""
        k = len(self.parts)
        poses, active, allowed, visible = [], [], [], []
        for i, name in enumerate(self.names):
            est = state.poses[name]
            poses.append((est.R, est.t))
            mask = None
            seen = bool(self.visibility[i] >= self.config.visible_fraction_full)
            if self.parts[i].color is not None and detections:
                det = detections.get(name)
                mask = self._blob_mask(det, depth.shape) if det is not None else None
                seen = mask is not None and int(mask.sum()) >= self.config.reseed_min_area_px
            active.append(bool(self.visibility[i] > 0.05) and (mask is None or bool(mask.any()))
                          and not (self.parts[i].color is not None and detections and mask is None))
            allowed.append(mask)
            visible.append(seen)
        corrections = self._refiner.refine(depth, poses, active, allowed)
        carried = np.asarray(self._carry.carried, bool).copy()
        released = self._was_carried & ~carried
        self._was_carried = carried
        self._cooldown = np.maximum(self._cooldown - 1, 0)
        for i in range(k):
            res = self._refiner.last[i]
            supported = res if corrections[i] is not None else None
            need = self._loss.update(i, supported, visible[i] and not carried[i], bool(released[i]))
            beyond = res is not None and corrections[i] is None and res.reason.startswith("correction beyond")
            if (need or beyond) and self._cooldown[i] == 0 and visible[i] and active[i]:
                starts = CUBE_STARTS if self.parts[i].box is not None else MESH_STARTS
                corr = reacquire(self._refiner, depth, i, poses[i][0], poses[i][1], allowed[i], starts)
                self._cooldown[i] = self.config.reacquire_cooldown
                self.n_reacquired += 1
                if corr is not None:
                    corrections[i] = corr
                    self._loss.reset(i)
        for i, corr in enumerate(corrections):
            if corr is None:
                continue
            name = self.names[i]
            ref = Pose.from_rt(corr.R, corr.t)
            if self._intersects_others(i, ref, state.poses):
                continue
            self.p[:, i], self.R[:, i] = corr.apply_to(self.p[:, i], self.R[:, i])
            state.poses[name] = ref
            state.particles[name] = self.p[:, i].astype(np.float32)
            self.estimates[name] = ref

    def _reuse_icp(self, obj: int, est: Pose, det) -> Pose | None:
        """The last ICP result of a part whose colour blob has not moved since (``icp_reuse_px``), else None: the
        depth points ICP would use are the same, so would be its answer; saves the registration."""
        cfg = self.config
        last = self._icp_last[obj]
        if cfg.icp_reuse_px <= 0.0 or last is None or det is None or last[3] >= cfg.icp_max_skipped:
            return None
        center = getattr(det, "center", None)
        if (center is None or getattr(det, "contour", None) is None
                or float(getattr(det, "score", 0.0) or 0.0) < cfg.color_mask_min_score):
            return None
        area = float(getattr(det, "area", 0) or 0)
        if np.linalg.norm(np.asarray(center, np.float64) - last[1]) > cfg.icp_reuse_px:
            return None
        if last[2] <= 0 or abs(area / last[2] - 1.0) > 0.05:
            return None
        self._icp_last[obj] = (last[0], last[1], last[2], last[3] + 1)
        return last[0]

    def _intersects_others(self, obj: int, pose: Pose, poses: dict[str, Pose]) -> bool:
        """Would part ``obj`` at ``pose`` interpenetrate another part's estimate (beyond the contact tolerance)?"""
        k = len(self.parts)
        if k < 2:
            return False
        R = np.stack([pose.R if i == obj else poses[n].R for i, n in enumerate(self.names)])[None]
        t = np.stack([pose.t if i == obj else poses[n].t for i, n in enumerate(self.names)])[None]
        pairs = np.array([(obj, o) for o in range(k) if o != obj], np.int64)
        return bool(intersection_flags(R, t, self.center, self.half, pairs, self.config.contact_tolerance)[0])

    def _blob_mask(self, det, shape) -> np.ndarray | None:
        """Full-resolution mask of a detection's blob, eroded by 2 px (edges mix part and background); computed
        once per detection object and frame (colour input, re-seeding and ICP all use it)."""
        key = id(det)
        if key not in self._blobs:
            self._blobs[key] = (det, self._make_blob_mask(det, shape))
        return self._blobs[key][1]

    def _make_blob_mask(self, det, shape) -> np.ndarray | None:
        if det is None or getattr(det, "contour", None) is None:
            return None
        if float(getattr(det, "score", 0.0) or 0.0) < self.config.color_mask_min_score:
            return None
        import cv2

        pts = np.asarray(det.contour, np.int32).reshape(-1, 2)
        x0, y0 = max(int(pts[:, 0].min()) - 3, 0), max(int(pts[:, 1].min()) - 3, 0)
        x1, y1 = min(int(pts[:, 0].max()) + 4, shape[1]), min(int(pts[:, 1].max()) + 4, shape[0])
        m = np.zeros(shape, bool)
        if x0 >= x1 or y0 >= y1:
            return m
        win = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillPoly(win, [pts - np.array([x0, y0], np.int32)], 1)
        m[y0:y1, x0:x1] = cv2.erode(win, np.ones((5, 5), np.uint8)).astype(bool)
        return m

    def _color_masks(self, detections, gi, gj) -> tuple[np.ndarray, np.ndarray]:
        """Per part, which evaluated pixels lie inside its detected colour blob (dilated by one grid pixel)."""
        k = len(self.parts)
        cmask = np.ones((k, gi.size), np.uint8)
        cvalid = np.zeros(k, np.uint8)
        cfg = self.config
        if not (cfg.color_mask_likelihood and detections):
            return cmask, cvalid
        import cv2

        f = cfg.downsample
        grid = (self._vs.size, self._us.size)
        for i, name in enumerate(self.names):
            det = detections.get(name)
            if det is None or self.parts[i].color is None:
                continue
            if getattr(det, "center", None) is None:
                if self._blob_seen[i] and cfg.color_mask_when_missing:
                    # the detector, which has found this part's colour before, finds no blob now: the part shows
                    # nowhere (empty mask), so depth that fits it (a hand over it) is no evidence for it
                    cmask[i] = 0
                    cvalid[i] = 1
                continue
            contour = getattr(det, "contour", None)
            if contour is None or float(getattr(det, "score", 0.0) or 0.0) < cfg.color_mask_min_score:
                continue
            self._blob_seen[i] = True
            pts = (np.asarray(contour, np.float64).reshape(-1, 2) - self._off) / f
            if pts.shape[0] < 3:
                continue
            m = np.zeros(grid, np.uint8)
            cv2.fillPoly(m, [np.round(pts).astype(np.int32)], 1)
            m = cv2.dilate(m, np.ones((3, 3), np.uint8))
            cmask[i] = m[gj, gi]
            cvalid[i] = 1
        return cmask, cvalid

    def _area_ratio(self, obj: int, area) -> float:
        """min(1, detected blob area / projected area of the part at its estimate); 1 when unknown.

        A part partly hidden by a hand has a blob whose centroid is biased toward the visible part, so the colour
        input is trusted in proportion to the visible fraction (an addition to eq. 3.7's score).
        """
        if area is None or not np.isfinite(area) or area <= 0:
            return 1.0
        est = self.estimates[self.names[obj]]
        pts = est.transform_points(self.hulls[obj])
        if np.any(pts[:, 2] < 0.01):
            return 1.0
        uv = self.intrinsics.project(pts).astype(np.float32)
        import cv2

        expected = float(cv2.contourArea(cv2.convexHull(uv)))
        if expected <= 1.0:
            return 1.0
        return float(min(1.0, area / expected))

    def _surface_fallback(self, obj: int) -> float:
        return float(self.half[obj].min())

    def _surface_depth(self, obj: int, center) -> float:
        """Depth (m) of the part's estimate at pixel ``center`` (inf = the pixel is off its silhouette; meshes: the
        estimate's centre depth when the pixel is within its bounding radius, else inf)."""
        est = self.estimates[self.names[obj]]
        if self.meshes[obj] is not None:
            uv = self.intrinsics.project(est.t[None])[0]
            rpx = self._radius[obj] * self.intrinsics.fx / max(float(est.t[2]), 0.05)
            inside = np.hypot(uv[0] - center[0], uv[1] - center[1]) <= rpx
            return float(est.t[2]) - self._surface_fallback(obj) if inside else np.inf
        ray = pixel_rays(self.intrinsics, np.array([center[0]]), np.array([center[1]]))
        out = np.full((1, 1), np.inf, np.float32)
        render_boxes_at_pixels(est.R[None, None], est.t[None, None], self.center[obj:obj + 1],
                               self.half[obj:obj + 1], 0, np.zeros(1, np.int64), ray,
                               np.array([float(center[0])]), np.array([float(center[1])]), np.zeros(1, np.int64),
                               self.intrinsics.fx, self.intrinsics.fy, self.intrinsics.cx, self.intrinsics.cy, out,
                               np.zeros((1, 1), np.int64), np.zeros((1, 1), np.uint8))
        return float(out[0, 0])

    def _reseed(self, obj: int, det, depth: np.ndarray) -> bool:
        """Re-draw ``reseed_fraction`` of part ``obj``'s particles (previous poses) around its colour blob: the
        centroid's ray at the blob's median depth plus half the part's smallest extent (std ``reseed_sigma``),
        velocity zero, orientation kept. The estimate is moved to the target as well. Returns whether it did."""
        cfg = self.config
        mask = self._blob_mask(det, depth.shape)
        if mask is None:
            return False
        vals = depth[mask]
        vals = vals[np.isfinite(vals) & (vals > 0)]
        est = self.estimates[self.names[obj]]
        if vals.size >= max(5, 0.2 * mask.sum()):
            zc = float(np.median(vals)) + self._surface_fallback(obj)
        else:  # no valid depth on the blob (sensor shadow next to a hand): keep the estimate's depth
            zc = float((est.R @ self.center[obj] + est.t)[2])
        ray = pixel_rays(self.intrinsics, np.array([float(det.center[0])]), np.array([float(det.center[1])]))[0]
        target = ray * zc - est.R @ self.center[obj]  # body origin whose box centre lies on the ray
        n = self.p.shape[0]
        m = int(round(cfg.reseed_fraction * n))
        if m <= 0:
            return False
        sel = np.sort(self.rng.choice(n, m, replace=False))
        self.p[sel, obj] = target + self.rng.normal(0.0, cfg.reseed_sigma, (m, 3))
        self.v[sel, obj] = 0.0
        self.estimates[self.names[obj]] = Pose.from_rt(est.R, target)
        self.n_reseeded += 1
        return True

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
            self._render(i, t, R, idx, rays, self._pu[:p], self._pv[:p], self._gi[:p], self._gj[:p], sub, D, loc,
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


def _union(a, b):
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
