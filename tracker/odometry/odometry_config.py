"""Settings of the camera odometry (:class:`OdometryConfig`). Lengths in metres, angles in degrees, grey levels
0..255. Tuned on simulator seeds 0–4 only."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class OdometryConfig:
    """Settings of :class:`~tracker.odometry.camera_odometry.CameraOdometry`.

    Dense alignment (method ``"dense"``):

    * ``levels``: pyramid levels used, coarse to fine (level l = image halved l times; 0 = full resolution, 3 =
      80×60 for VGA).
    * ``iterations``: Gauss-Newton iterations per used level (same order as ``levels``).
    * ``second_start_m`` / ``second_start_deg``: when the constant-velocity prediction is farther than this from the
      last pose, the frame is also aligned from the last pose and the plausible result with more inliers is taken (a
      wrong registration's velocity otherwise puts the next start near a wrong minimum, which the alignment then
      takes: a runaway); 0 = off.
    * ``retry_levels`` / ``retry_iterations``: when a frame's result is rejected (too few inliers or an implausible
      jump), it is aligned once more with these levels (a coarser start widens the basin of convergence), first from
      the prediction, then from the last measured pose; empty = no retry.
    * ``n_photo`` / ``n_geo``: photometric / geometric points sampled per keyframe level.
    * ``min_gradient``: smallest image gradient (grey levels per pixel) of a photometric point.
    * ``photo_weight``: weight of the photometric term relative to the point-to-plane term (both residuals are
      divided by their robust scale first).
    * ``max_geo_distance``: point-to-plane correspondences farther than this (metres) are dropped.
    * ``robust``: ``"tukey"`` (biweight: gross outliers such as a part moved since the keyframe get no weight) or
      ``"huber"``; ``tukey`` / ``huber``: their thresholds in robust standard deviations.
    * ``min_photo_sigma`` / ``min_geo_sigma``: floors of the robust scales (grey levels / metres).
    * ``prior_sigma_m`` / ``prior_sigma_deg``: standard deviations of a Gaussian prior on the deviation from the
      constant-velocity prediction (0 = no prior); it decides only directions the images leave undetermined
      (e.g. sliding along a textureless table while a hand hides the parts).
    * ``converged_m`` / ``converged_rad``: a level stops iterating when the update is smaller than both.
    * ``min_inliers``: fewest valid correspondences (both terms together, finest level) for a pose to count.
    * ``max_step_m`` / ``max_step_deg``: a result farther than this from the constant-velocity prediction is
      rejected (the pose then follows the prediction and is flagged).

    Keyframes:

    * ``keyframe_distance_m`` / ``keyframe_angle_deg``: a new keyframe is taken when the camera is this far from
      the nearest keyframe (and no stored keyframe is closer); ``keyframe_min_overlap``: or when fewer than this
      share of the keyframe's geometric points are seen in the current frame.
    * ``keyframe_max_masked``: a frame with more than this share of its pixels masked (hands) does not become a
      keyframe while it still sees ``keyframe_last_overlap`` of the keyframe's geometric points: its pose is the
      least certain (the hands hide what fixes it) and a keyframe would keep that error for every later frame.
    * ``max_keyframes``: keyframes kept (the oldest except the first is dropped beyond it).

    FastSLAM (method ``"fastslam"``, see :mod:`tracker.odometry.fastslam`) has its own
    :class:`~tracker.odometry.fastslam.FastSlamConfig`.
    """

    levels: tuple[int, ...] = (2, 1, 0)
    iterations: tuple[int, ...] = (10, 8, 6)
    second_start_m: float = 0.01
    second_start_deg: float = 1.0
    retry_levels: tuple[int, ...] = (3, 2, 1, 0)
    retry_iterations: tuple[int, ...] = (10, 8, 6, 4)
    n_photo: int = 3000
    n_geo: int = 3000
    min_gradient: float = 3.0
    photo_weight: float = 1.0
    max_geo_distance: float = 0.03
    robust: str = "huber"
    huber: float = 1.345
    tukey: float = 4.685
    min_photo_sigma: float = 1.0
    min_geo_sigma: float = 0.0005
    prior_sigma_m: float = 0.0
    prior_sigma_deg: float = 0.5
    converged_m: float = 2e-5
    converged_rad: float = 2e-5
    min_inliers: int = 300
    max_step_m: float = 0.05
    max_step_deg: float = 5.0
    keyframe_distance_m: float = 0.03
    keyframe_angle_deg: float = 3.0
    keyframe_min_overlap: float = 0.6
    keyframe_max_masked: float = 0.25
    keyframe_last_overlap: float = 0.3
    max_keyframes: int = 50

    def __post_init__(self) -> None:
        if not self.levels or len(self.levels) != len(self.iterations):
            raise ValueError("OdometryConfig: levels and iterations must be non-empty and of equal length")
        if any(lv < 0 for lv in self.levels) or any(n < 1 for n in self.iterations):
            raise ValueError("OdometryConfig: levels must be >= 0 and iterations >= 1")
        if len(self.retry_levels) != len(self.retry_iterations) or any(lv < 0 for lv in self.retry_levels) or \
                any(n < 1 for n in self.retry_iterations):
            raise ValueError("OdometryConfig: retry_levels and retry_iterations must be of equal length, levels >= 0, "
                             "iterations >= 1")
        if self.n_photo < 0 or self.n_geo < 0 or self.n_photo + self.n_geo == 0:
            raise ValueError("OdometryConfig: n_photo + n_geo must be positive")
        if self.robust not in ("tukey", "huber"):
            raise ValueError(f"OdometryConfig: robust must be 'tukey' or 'huber', got {self.robust!r}")
        if self.max_keyframes < 1:
            raise ValueError("OdometryConfig: max_keyframes must be >= 1")

    @property
    def n_levels(self) -> int:
        """Pyramid depth needed (deepest used level + 1, the retry's included)."""
        return max(self.levels + self.retry_levels) + 1

    @property
    def retry(self) -> OdometryConfig | None:
        """These settings with the retry's levels and iterations (None when there is no retry)."""
        if not self.retry_levels:
            return None
        return replace(self, levels=self.retry_levels, iterations=self.retry_iterations, retry_levels=(),
                       retry_iterations=(), second_start_m=0.0, second_start_deg=0.0)

    @classmethod
    def half_resolution(cls) -> OdometryConfig:
        """The settings before the full-resolution level was added (:data:`HALF_RESOLUTION`): the tracker's own
        ``--odometry default`` keeps them (its exclusion mask is made at half resolution)."""
        return cls(**HALF_RESOLUTION)

    @classmethod
    def fast(cls) -> OdometryConfig:
        """The settings of the dense step inside the fused odometry (:data:`FAST`): half the points, fewer
        iterations, a looser convergence test; the fused path's prediction is its start and its check."""
        return cls(**FAST)

    def with_overrides(self, **kw) -> OdometryConfig:
        names = {f.name for f in fields(self)}
        unknown = set(kw) - names
        if unknown:
            raise ValueError(f"OdometryConfig: unknown setting(s) {', '.join(sorted(unknown))}")
        return replace(self, **kw)


HALF_RESOLUTION = {"levels": (3, 2, 1), "iterations": (10, 8, 6), "retry_levels": (), "retry_iterations": (),
                   "second_start_m": 0.0, "second_start_deg": 0.0, "keyframe_max_masked": 1.0}
"""Overrides of :meth:`OdometryConfig.half_resolution`: levels 80×60 to 320×240, no retry (the defaults up to
session 15). The defaults since: levels 160×120 to 640×480, and the 80×60 level only in a retry of a rejected frame.
Tuning sessions (seeds 0–4, 300 frames, ground-truth hand boxes masked, ATE mm
half-resolution → defaults): static hand-held 0 0.42 → 0.28, guess-1 hand-held 1 7.03 → 2.52, guess-1 hand-held 2
1.74 → 0.88, guess-3 sway 3 2.51 → 1.00, learning-4 hand-held 4 0.40 → 0.24; on castle-simu (external development
set) 4.94 → 2.45. The 80×60 level moved good starts 10–20 mm off on a plank-textured table (its grain vanishes there
and the planks' lines leave a direction undetermined); the full-resolution level with it (no retry) accepted two
wrong steps on guess-3 sway 3 whose velocity then ran away (16.6 mm).

``keyframe_max_masked`` 0.25 (was: no limit): a frame whose hand mask covered 43–49 % of the image became a keyframe
(the mask cut its overlap with the old one) 34 mm off, and every later frame kept that error (guess-1 hand-held 2,
every 5th frame). The five tuning sessions at 1×, 3× and 5× the camera speed (every frame, every 3rd, every 5th):
mean ATE 2.79 → 0.93 mm, worst 23.9 → 2.7 mm (5×: 6.6 → 2.1, 23.9 → 0.36 mm), but slightly worse at 1× (sum of the
five 4.17 → 4.68 mm; learning-4 0.22 → 0.66 mm), where the old keyframe is kept over a hand-covered stretch."""

FAST = {"n_photo": 1500, "n_geo": 1500, "levels": (3, 2, 1), "iterations": (8, 6, 4), "converged_m": 1e-4,
        "converged_rad": 1e-4, "retry_levels": (), "retry_iterations": (), "second_start_m": 0.0,
        "second_start_deg": 0.0, "keyframe_max_masked": 1.0}
"""Overrides of :meth:`OdometryConfig.fast`. Tuning-seed replay of the in-tracker odometry's inputs (guess-1
hand-held seed 1, 120 frames): alignment 10.8 → 1.8 ms thread CPU per frame, chain error against the truth 2.35 →
1.76 mm RMS. Alone (no fused prediction to start from) they failed with a hand moving parts on a held-out session
(ATE 118 mm against 4 mm with the defaults), so the standalone dense odometry keeps the defaults."""
