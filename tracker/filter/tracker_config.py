"""Settings of the multi-object depth tracker (spec sections 4, 9, 10 and 15).

Every parameter the spec names is a field here with its unit and source. Presets:

* ``"seed-exp1"``  — the thesis's Experiment 1 values (spec section 15, "Experiment 1").
* ``"seed-exp23"`` — the thesis's Experiments 2/3 values.
* ``"default"``    — the values tuned for this product (see benchmarks/results/tracker.md).

Both seed presets use the reference-code defaults (dbot / dbot_ros) for what the thesis leaves open, and the
reference likelihood resolution (depth downsampled by 8). Override any field from a YAML or TOML file with
:meth:`TrackerConfig.load` (keys are field names; an optional ``preset`` key selects the base preset).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError


class TrackerConfig(BaseModel):
    """All tracker settings. Units: metres, seconds, radians; "per step" = per processed frame."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    # --- particle filter (spec 4.3, 4.4, 4.12, 4.16)
    n_particles: int = Field(225, ge=1, description="N, total number of particles (thesis: 225 for real time).")
    kl_max: float = Field(1.0, ge=0.0, description="D_KL,max resampling threshold, natural log (thesis 0.5 / 1).")

    # --- dynamic model (spec 4.7)
    b: float = Field(0.3, description="Input coefficient b of the colour control input (4.24-4.26).")
    k_v: float = Field(0.2, description="Velocity coefficient k_v (4.24-4.26).")
    sigma_v: float = Field(0.005, ge=0.0, description="Linear noise std sigma_v, metres per step.")
    sigma_w: float = Field(0.05, ge=0.0, description="Angular noise std sigma_omega, radians per step.")
    velocity_model: str = Field(
        "seed", pattern="^(seed|constant)$", description="'seed': per-particle velocities damped by k_v (4.26); "
        "'constant': constant velocity estimated from the refined estimates, with noise that grows with the speed "
        "(filter/predict.py).",
    )
    cv_gain: float = Field(0.8, ge=0.0, le=1.0, description="Constant velocity: factor on the estimated velocity.")
    cv_smoothing: float = Field(
        0.5, gt=0.0, le=1.0, description="Constant velocity: weight of the newest velocity in its running mean.",
    )
    cv_noise_gain: float = Field(
        0.5, ge=0.0, description="Constant velocity: motion noise factor 1 + cv_noise_gain * speed / sigma_v.",
    )
    cv_noise_max: float = Field(5.0, ge=1.0, description="Constant velocity: largest motion noise factor.")
    wide_noise_fraction: float = Field(
        0.0, ge=0.0, le=1.0, description="Share of noise samples drawn with wide_noise_scale x the stds (a Gaussian "
        "mixture proposal; 0 = the spec's single Gaussian).",
    )
    wide_noise_scale: float = Field(1.0, ge=1.0, description="Std multiplier of the wide noise component.")
    hidden_noise_scale: float = Field(
        1.0, gt=0.0, le=1.0, description="Noise std multiplier of a part that is fully hidden (visible fraction 0, "
        "from the occlusion posterior); 1 = off (the spec). Hidden parts otherwise drift toward the occluder.",
    )
    rest_prior_sigma: float = Field(
        0.0, ge=0.0, description="Rest prior (not in the spec; 0 = off): a part without a reliable colour blob whose "
        "estimated visible fraction is below rest_prior_max_visibility is taken to be at rest (cubes move only in "
        "the hand, and then their blob moves): its velocity is zeroed and each particle's weight gets "
        "-|p - p_rest|^2 / (2 sigma^2) (capped at 9 sigma^2), p_rest = its position at the last frame with a "
        "reliable blob and visibility >= visible_fraction_full. Keeps the occlusion likelihood from dragging a "
        "hidden part toward the occluder. Metres.",
    )
    rest_prior_max_visibility: float = Field(
        0.3, ge=0.0, le=1.0, description="Visible fraction below which an undetected part gets the rest prior.",
    )
    rest_prior_rotation: bool = Field(
        False, description="While the rest prior holds a part, its particles keep the rotation of its rest anchor "
        "(the estimate of the last frame with a reliable blob and visibility >= visible_fraction_full, moved with the "
        "camera and the hand like the anchor's position): a refinement pulled by a hand covering the part does not "
        "leave it turned for as long as it stays hidden.",
    )
    rest_anchor_moving: bool = Field(
        False, description="A part that moves (carried by a hand or moving with its colour blob) and that this "
        "frame's dense-depth refinement placed takes its refined pose as its rest anchor even when it is only partly "
        "seen: a part picked up and turned while half in the hand is held, once hidden, where it was last seen and "
        "not where it was last seen whole.",
    )
    resting_upright_deg: float = Field(
        0.0, ge=0.0, le=45.0, description="Degrees (0 = off): a box part resting on the table (lowest point within "
        "carry_min_height of it, not carried, not moving with its blob) whose estimate is tilted from lying on a "
        "face by less than this is turned upright about its centre after the refinement.",
    )
    carry_upright_air: bool = Field(
        False, description="With table_upright: a box part carried hidden is turned upright (its box axis nearest to "
        "the table normal along the normal, about its centre) after each frame's hand motion in the air as well, not "
        "only within carry_min_height of the table: a hand carries a part the way it picked it up from the table, and "
        "a tilt it picked up (a refinement of the partly seen part as it vanished, the hand registration's noise) "
        "would otherwise be carried to the end of the hidden carry.",
    )
    contact_align_deg: float = Field(
        0.0, ge=0.0, le=45.0, description="Degrees (0 = off; tracker/refine/contact_align.py): a resting box part "
        "refined this frame that touches a resting box part face to face, whose refinement matched at least 1.5 "
        "times as many depth points, is turned about its centre onto the nearest rotation with its faces parallel to "
        "that neighbour's when the turn is smaller than this (connected parts touch with parallel faces; a half "
        "hidden one is placed by one or two faces only).",
    )
    rest_anchor_motion: bool = Field(
        False, description="With rest_anchor_moving: a part that this frame's refinement places more than "
        "carry_min_motion from its rest anchor counts as moving as well (it has left the place where it rested), so a "
        "part a hand moves while it is still partly seen, before its carry starts, takes its refined pose as rest "
        "anchor; "
        "without, the anchor stayed where it was last fully seen (a hand whipping a part 7 cm and 13 degrees "
        "before it vanished in the hand: once hidden, the rest prior turned it back to that stale rotation).",
    )
    carry_hidden_skip: float = Field(
        0.0, ge=0.0, le=1.0, description="A part the hand carry moved this frame, without a reliable colour blob and "
        "with an estimated visible fraction below this, skips its coordinate pass (0 = never): it moves with the "
        "hand's registration alone.",
    )
    table_upright: bool = Field(
        False, description="A box-shaped part on the table that the depth does not place lies on one of its faces: "
        "when it rests unseen (support prior on), or is carried hidden with its lowest point within carry_min_height "
        "of the table, its rotation is turned by the least angle that puts its box axis nearest to the table normal "
        "along the normal (tilt picked up from a hand's registration noise is dropped; its turn about the normal is "
        "kept).",
    )
    rest_release_px: float = Field(
        4.0, ge=0.0, description="The rest prior is off for a part whose colour blob (however small) reaches more "
        "than this many pixels beyond the part's projected bounding rectangle at its rest position: it is moving "
        "(0 = never released this way).",
    )
    support_prior_sigma: float = Field(
        0.0, ge=0.0, description="Support prior (not in the spec; 0 = off; needs carry_follow and the table plane): a "
        "part below rest_prior_max_visibility that is not carried and not on another part rests on the table: its "
        "particles' weights get -h^2/(2 sigma^2) for the height h (m) of their lowest point above the table "
        "(linear beyond 3 sigma). Keeps a part in the depth sensor's shadow from floating toward the camera.",
    )
    carry_follow: bool = Field(
        False, description="Hand carry (not in the spec; filter/hand_carry.py): a hidden part (no reliable blob, "
        "visible fraction below rest_prior_max_visibility) that was moving or in the air when it disappeared is "
        "in the hand that hides it and follows the hand's depth points above the table (translation ICP).",
    )
    carry_min_motion: float = Field(
        0.015, gt=0.0, description="Distance (m) the estimate must travel in carry_window_s to count as moving.",
    )
    carry_window_s: float = Field(0.4, gt=0.0, description="Window (s) of the hand-carry motion test.")
    carry_min_height: float = Field(
        0.01, ge=0.0, description="Height (m) above the table from which a part is in the air (hand carry), and "
        "from which depth points count as hand points.",
    )
    carry_radius: float = Field(0.08, gt=0.0, description="Radius (m) of the hand patch around a carried part.")
    carry_patch_radius: float = Field(
        0.0, ge=0.0, description="Radius (m) of the hand patch that a carry registers from frame to frame once it has "
        "started, when larger than carry_radius (0 = carry_radius; whether the hand is still there is judged in "
        "carry_radius as before). The part sits behind the hand's visible surface, so carry_radius's sphere around it "
        "cuts a small cap of the hand: on a traced hidden carry (guess-1 fixed camera, tuning seed 2) its registration "
        "moved the part 0.45 mm a frame toward the camera on average (0.49 mm with the hand still) with 0.5-1 mm of "
        "noise; a 0.10 m patch 0.12 mm and 0.15-0.3 mm.",
    )
    carry_projective: int = Field(
        0, ge=0, description="Rounds (0 = off) of a projective point-to-plane refinement of a carry's frame-to-frame "
        "hand registration (geometry/projective_icp.py): each moved hand-patch point is paired with the pixel it "
        "projects to in the full-resolution depth image, not its nearest thinned hand point. On a convex hand the "
        "nearest-neighbour pairing pulls the patch outward, toward the camera: on a traced hidden carry (guess-1 fixed "
        "camera, tuning seed 2, frames 74-104) 0.57 mm a frame along the viewing ray (sd 1.1), with it 0.08 (sd 0.5); "
        "its error across the ray 0.74 -> 0.35 mm a frame. With carry_rotation and carry_rotation_axis 'free' only.",
    )
    carry_min_points: int = Field(
        10, ge=1, description="Fewest hand points in the window; fewer ends the carry (the hand has gone).",
    )
    carry_iterations: int = Field(8, ge=1, description="ICP rounds per frame of the hand-patch registration.")
    carry_max_step: float = Field(0.03, gt=0.0, description="Largest hand motion (m) per frame a carried part follows.")
    carry_rotation: bool = Field(
        True, description="Carried parts turn with the hand (rigid registration of the hand patch); off = they follow "
        "its translation only.",
    )
    carry_rotation_axis: str = Field(
        "free", pattern="^(free|table)$", description="Axis of a carried part's rotation: 'free' (any, from the hand "
        "patch) or 'table' (about the table normal only, when the plane is known).",
    )
    carry_max_turn: float = Field(
        0.2, gt=0.0, description="Largest hand rotation (rad) per frame a carried part follows.",
    )
    carry_start_register: bool = Field(
        False, description="A carry starts with the hand points around the part in the previous frame's depth, "
        "registered to this frame's (first guess: the part's own last step): the part moves with the hand from the "
        "first frame of the carry instead of standing still for one frame.",
    )
    carry_backtrack: int = Field(
        0, ge=0, description="A carry started by the motion test (the estimate moving, or in the air) of a part that "
        "the dense-depth refinement last placed 1 to carry_backtrack frames before the previous one starts from that "
        "placed pose, moved by the hand's motion since (the hand points of each kept depth image registered to the "
        "next, then to this frame's): a part lifted fast vanishes in the hand while the filter's constant-velocity "
        "prediction lags it, and the carry would keep that lag (1-3 cm, mostly along the viewing ray) to the end. "
        "0 = off (the carry starts from the current estimate).",
    )
    carry_backtrack_rest_m: float = Field(
        0.0, ge=0.0, description="With carry_backtrack: a carry started by the motion test (the estimate moving, or "
        "in the air), the see-through test (carry_revealed_fraction) or the table showing through (carry_left_table) "
        "of a part that the refinement has not placed within carry_backtrack frames (hidden at rest under the hand "
        "that then takes it) starts from the position its estimate had in the last frame in which it moved by at "
        "most this much (m) since the frame before (still at rest; 1 to carry_backtrack frames before the previous "
        "one), moved by the hand's motion since, as carry_backtrack does from a placed pose (instead of the shadow's "
        "shift, which counts the hand's motion over the part before it took it, or the hand points' centroid): the "
        "estimate of a hidden part a hand lifts lags it, mostly along the viewing ray, until one of those tests fires "
        "(14-23 mm on tuning traces), and the carry would keep that lag. 0 = off.",
    )
    carry_lift_lookback: bool = Field(
        False, description="With carry_backtrack: a hidden resting part taken by the hand (the table showing through "
        "its place, carry_left_table; the see-through test; a tracked hand's touch) whose carry cannot start because "
        "fewer than carry_min_points hand points lie within carry_radius of its place in this and the previous frame "
        "(the hand has lifted it away before the test fired: its estimate, held by the rest prior, stays behind) "
        "starts from its place moved by the hand's motion since the oldest kept frame (1 to carry_backtrack frames "
        "before the previous one) with that many hand points around the place, the hand points of each kept depth "
        "image registered to the next as carry_backtrack does; without it the part stays behind until its blob shows "
        "(a cube lifted 6 cm toward the camera in 4 frames stayed 95 mm behind for 13 frames on a tuning trace).",
    )
    carry_start_placed_step: bool = Field(
        False, description="With carry_start_register and carry_backtrack: a carry's first registration (the previous "
        "frame's hand points to this frame's) also starts from the part's last step as the dense-depth refinement "
        "placed it (its placed positions in the two previous frames), beside no motion and its estimate's remembered "
        "step; the start leaving the smaller residual wins. So does a backtracked start's first registration (from "
        "the frame of its last placement), from the step between that placement and the one in the frame before. A "
        "part slid or lifted 2-3 cm a frame while seen is re-seeded on its blob every frame, and each re-seed wipes "
        "its remembered positions (the jump is no motion for the motion test), so the registration started from no "
        "motion only and, with the hand's step beyond the 2 cm pairing bound, slid 2-3 cm toward the camera (two "
        "tuning traces, tracker seed 1: 11-31 mm; the carry then kept that offset to its end, 30-40 mm at p95).",
    )
    carry_start_collapse: bool = Field(
        False, description="A part whose carry starts this frame from its estimate (not backtracked; a backtracked "
        "start collapses already) has every particle put at the pose the hand's motion gave it, velocities zero, "
        "before its coordinate pass: the cloud a fast part still partly seen was spread over (re-seeds on its blob, "
        "wide noise; 25 mm on a tuning trace) is not left around a right carry start for the likelihood on its few "
        "visible pixels to pick from (the pass pulled a start 1 mm right 23 mm off, and the refinement failed there).",
    )
    carry_start_skip: bool = Field(
        False, description="A part whose carry starts this frame and that the hand's motion moved skips its "
        "coordinate pass this frame (as carry_hidden_skip skips a hidden carried part's): its first carried pose is "
        "the hand's registration's, not a pick among its particles by the likelihood on the few pixels of it the hand "
        "leaves visible. Alone it hardly acts (22.6 against 23.5 mm on the tuning trace): the frame's first "
        "likelihood, at the prediction of all parts, weighs the joint particles by its pixels as well. Meant with "
        "carry_start_collapse.",
    )
    refined_collapse_m: float = Field(
        0.0, ge=0.0, description="Metres (0 = off): a part that this frame's dense-depth refinement placed (a healthy, "
        "accepted correction; not a held one) while its particles are spread wider than this (the norm of their "
        "weighted per-axis standard deviations) has every particle put at the refined pose, velocities zero: a cloud "
        "that a re-seed on the blob of a partly seen part (at a release, or by the colour stage) left spread over "
        "2-3 cm is not left around a pose the depth confirmed for the next frame's likelihood on its few visible "
        "pixels to pick from (a tuning trace: a release re-placed 6.8 mm off, the next pass pulled it 27.8 mm off "
        "toward the particles still at the carried pose, and the refinement failed there).",
    )
    carry_turn_fallback: bool = Field(
        False, description="A hand-patch registration that turns more than carry_max_turn in one frame has failed "
        "(a fast move mismatched its point pairs): the carried part follows the translation-only registration, "
        "not a turn capped at carry_max_turn.",
    )
    carry_blob_radii: float = Field(
        1.0, ge=0.0, description="A carried part whose confident colour blob (however small) shows farther than this "
        "many projected bounding radii from its estimate is released and re-seeded at the blob (0 = off).",
    )
    carry_revealed_fraction: float = Field(
        0.0, ge=0.0, le=1.0, description="A hidden part whose projected silhouette shows valid depth on at least this "
        "fraction, nearly all well behind the part, is not there: it is put in the hand nearest to it and carried "
        "(0 = off).",
    )
    carry_shadow: bool = Field(
        False, description="While a resting part is hidden under a hand, the hand's motion is followed as if it "
        "carried the part (a shadow carry); when the part turns out not to be where it was (carry_revealed_fraction), "
        "it is moved by that motion and carried on, instead of being put at the centroid of the hand points near "
        "where it was.",
    )
    carry_shadow_restart: bool = Field(
        False, description="With carry_shadow: a hidden resting part whose shadow lost its hand (the hand left) having "
        "followed it less than the part's bounding radius (too little to take the part) starts a new shadow when hand "
        "points are back around its place; without it the shadow ends for good and a hand that comes back and lifts "
        "the part has no motion to carry it from.",
    )
    carry_shadow_take_m: float = Field(
        0.0, ge=0.0, description="A hidden resting part whose shadow carry (carry_shadow) has followed the hand over "
        "it this far (m) with the hand still in view is taken to be in that hand: moved by the hand's motion and "
        "carried on, without waiting for its place to be seen through (0 = off; an arm can cover the place the whole "
        "time).",
    )
    carry_left_table: float = Field(
        0.0, ge=0.0, le=1.0, description="A hidden resting part over whose silhouette the depth shows the table top on "
        "at least this fraction of the pixels with depth (more than show its surface) has been picked up: its carry "
        "starts at once, moved by the hand's motion since it hid the part (its carry_shadow) or by this frame's "
        "(filter/footprint_depth.py; the motion test waits for the estimate to move, which the rest prior "
        "prevents; 0 = off).",
    )
    revealed_surface: bool = Field(
        False, description="The see-through test of carry_revealed_fraction compares the depth with the estimate's "
        "rendered surface at each pixel (1.5 cm behind it) instead of with its far side: a box resting on the table "
        "has the table right under it, never 1.5 cm behind its far side, so a box snatched from the table was only "
        "noticed once its blob showed up elsewhere.",
    )
    carry_keep_visibility: float = Field(
        0.0, ge=0.0, le=1.0, description="A carry starts below rest_prior_max_visibility but ends only when the "
        "part's estimated visible fraction reaches this (hysteresis; 0 or less than rest_prior_max_visibility = "
        "off): a part coming out of the hand is moved with it, as a prediction its depth then corrects, instead "
        "of being dropped by a one-frame rise of the estimate while the hand still moves it.",
    )
    carry_keep_unseen: float = Field(
        0.0, ge=0.0, le=1.0, description="A carried part whose estimate was visible enough last frame to end its "
        "carry stays in the hand this frame unless this frame's depth still shows it where it was: less than this "
        "fraction of its silhouette's pixels (at the estimate before the hand's motion) within 1 cm of the depth "
        "(0 = off). The test is on this frame's depth, not on last frame's visible fraction: a hand that whips a "
        "part out of view in one frame took it along, a hand that lets go leaves it in view.",
    )
    carry_keep_moving: float = Field(
        0.0, ge=0.0, description="Metres (0 = off): a carried part whose last estimate was visible enough to end its "
        "carry is registered with the hand all the same and stays in it when this frame's hand motion moves its "
        "centre by at least this much and this frame's depth shows it better where the hand takes it than where it "
        "was (a cube 35 % seen in a hand moving it 1 cm a frame was dropped for one frame by its visible fraction "
        "crossing rest_prior_max_visibility, re-checked on its sliver 21 degrees off and carried on so).",
    )
    carry_keep_moving_pre_reseed: bool = Field(
        False, description="With carry_keep_moving and carry_over_sliver: a part the colour stage has re-seeded on its "
        "blob this frame is tested from the pose it had before that re-seed (the pose the hand's registration moved "
        "and carry_over_sliver moves), not from the re-seeded estimate: the hand's step added to the re-seed, which "
        "has already moved it along its blob, counted the frame's motion twice (a cube carried 37 mm a frame, 30 % "
        "seen, was tested 55 mm off and dropped for a frame, 20 mm off, on a tuning trace; from its last pose the "
        "hand's step puts it 2.3 mm from the truth).",
    )
    carry_shift_starts: float = Field(
        0.0, ge=0.0, description="Metres (0 = off): the hand-patch registration of a carry (every frame, and a "
        "backtracked start's) also starts from its first guess shifted by this much along each camera axis (six more "
        "starts of the compiled ICP); one of them is taken only when its mean residual (clipped at the 2 cm pairing "
        "bound) is lower than the usual starts' best by more than 1 mm: a hand moving 3-4 cm a frame, beyond the "
        "pairing bound, from a wrong first guess settles in a wrong minimum (6.9-8.4 mm residual on a tuning trace, "
        "20-27 mm off) that a start within 2 cm of the true step leaves (2.3 mm).",
    )
    carry_blob_depth: bool = Field(
        False, description="A carried part whose reliable blob lies off its silhouette (the colour stage re-seeds it "
        "on the blob's ray, at its old depth when the blob has no depth) is turned by the hand's motion and put on "
        "that ray at the depth the hand's motion gives it, instead of keeping the re-seed's depth and turn (a part "
        "carried toward the camera fell behind by the hand's whole motion along the ray).",
    )
    carry_reacquire_keep_turn: bool = Field(
        False, description="A part re-acquired while carried is refitted from its own rotation only (the hand's "
        "motion turned it), not from the other start rotations: a sliver of a part in a hand fits a wrong face as "
        "well as the right one.",
    )
    carry_rest_prior: bool = Field(
        False, description="A part the hand carry moved this frame while it is hidden (estimated visible fraction "
        "below rest_prior_max_visibility) gets the rest prior at the pose the hand's motion gave it (anchor, rotation, "
        "rest_prior_sigma): its coordinate pass, which has only the hand's surface to go by, cannot walk it away "
        "from the hand.",
    )
    carry_anchor_start: bool = Field(
        False, description="When a carry starts, the part's rest anchor (position and rotation) is set to its "
        "estimate, and moves with the hand from there: the rest prior of the hidden carried part holds the pose it "
        "had as it vanished in the hand, not a stale one from where it was last fully seen (a hand that moved and "
        "turned a half-seen cube before its carry started left the anchor 7 cm and 13 degrees back; once hidden, "
        "the rest prior's rotation turned the cube to it).",
    )
    carry_over_sliver: bool = Field(
        False, description="A hidden part in a moving hand whose sliver of colour blob lies off its silhouette (the "
        "colour stage re-seeds it on the blob's ray) moves with the hand's motion from where it was before that "
        "re-seed, unless the blob's centroid lies farther than carry_blob_radii projected bounding radii from "
        "where the hand takes its centre: a sliver's centroid is not the part's centre, and a re-seed on it left a "
        "cube carried 3 cm a frame 2 cm off for the rest of its hidden carry. The hand's registration also starts "
        "from the hand points around the part's place before the re-seed.",
    )
    carry_sliver_particles: bool = Field(
        False, description="With carry_over_sliver: the part's particles move with the hand from where they were "
        "before the re-seed on its sliver, which is undone (without it the particles are moved rigidly with the "
        "estimate, so the 70 % not re-drawn around the sliver's centroid land the re-seed's jump, 3-5 cm on tuning "
        "traces, away from where the hand takes the part, and the coordinate passes pull the estimate toward them).",
    )
    carry_keyframe: bool = Field(
        False, description="Each frame's hand motion is corrected by registering the carry's first hand patch, moved "
        "by every motion since, to the current hand points (at most 5 mm and 0.05 rad): the frame-to-frame errors of "
        "a long carry do not add up while the hand keeps its shape.",
    )
    carry_keyframe_inliers: float = Field(
        0.5, ge=0.0, le=1.0, description="Fraction of the keyframe's points that must lie within 5 mm of the current "
        "hand points after its registration; below it the keyframe starts again from the current patch.",
    )
    carry_stride: int = Field(2, ge=1, description="Pixel stride (full resolution) of the hand points.")
    visible_fraction_full: float = Field(
        0.5, gt=0.0, le=1.0, description="Visible fraction from which a part gets its full motion noise.",
    )

    # --- colour input (spec 4.11)
    lambda_z: float = Field(1.0, ge=0.0, le=1.0, description="Damping lambda_z of the depth component u_z.")
    depth_radius_px: float = Field(
        4.0, ge=0.0, description="R: radius (full-resolution pixels) of the depth average around the colour pixel."
    )
    min_detection_score: float = Field(
        0.05, ge=0.0, le=1.0, description="Detections with a lower score count as 'not detected' (u = 0)."
    )

    color_likelihood_px: float = Field(
        0.0, ge=0.0, description="Std (pixels) of an optional colour term in the particle weights: "
        "-s/2 min(d^2, 9 std^2)/std^2 with d the distance of the projected part centre from the colour detection "
        "(not in the spec, which uses colour only as control input; 0 = off).",
    )
    color_term_dead_zone: float = Field(
        0.0, ge=0.0, description="Colour term measured from the part's projected inscribed circle instead of its "
        "centre: d = max(0, |centroid - projected centre| - this x smallest half extent x f/z), and weighted by the "
        "full score (the blob centroid of a partly hidden part stays inside its silhouette). 0 = centre distance, "
        "area-weighted score.",
    )
    color_mask_likelihood: bool = Field(
        False, description="Use the colour blobs in the depth likelihood: a pixel outside a part's detected blob "
        "cannot show that part, so it counts as occluded there (not in the spec; keeps a hand from being taken "
        "for the part it holds). Parts without colour or detection stay depth only.",
    )
    color_mask_when_missing: bool = Field(
        False, description="With color_mask_likelihood: a coloured part whose blob the detector has found before "
        "but finds no longer shows nowhere: every pixel counts as occluded for it (a hand over it is no evidence "
        "for it). Off: such a part is tracked on depth alone.",
    )
    color_mask_min_score: float = Field(0.5, ge=0.0, le=1.0, description="Minimum score for using a blob mask.")
    color_area_weighting: bool = Field(
        True, description="Scale the reliability s by min(1, blob area / projected part area) (not in the spec: a "
        "partly hidden part's blob centroid is biased).",
    )
    color_visible_centroid: bool = Field(
        False, description="Compare a blob's centroid with the centroid of the part's expected visible region (its "
        "estimate's silhouette less the pixels whose measured depth lies more than color_occluded_margin in front "
        "of it: a hand, another part), not with its projected centre (not in the spec): a part half under a hand "
        "shows a blob whose centroid is off its centre, and the colour input no longer pulls it that way.",
    )
    color_occluded_margin: float = Field(
        0.01, gt=0.0, description="Depth (m) in front of the estimate's surface from which a silhouette pixel counts "
        "as occluded for color_visible_centroid.",
    )

    reseed_fraction: float = Field(
        0.0, ge=0.0, le=1.0, description="Re-seeding (not in the spec): when a part's colour blob is reliable "
        "(score >= reseed_min_score, area >= reseed_min_area_px) but its centroid lies off the part's estimated "
        "silhouette, this share of the part's particles is re-drawn around the blob (centroid ray, blob median depth "
        "+ half the smallest extent) before the prediction; the likelihood then decides. 0 = off.",
    )
    reseed_sigma: float = Field(0.008, gt=0.0, description="Std (m) of the re-seeded positions around the target.")
    reseed_min_score: float = Field(0.5, ge=0.0, le=1.0, description="Minimum detection score for re-seeding.")
    reseed_min_area_px: float = Field(40.0, ge=0.0, description="Minimum blob area (full-res px) for re-seeding.")
    reseed_min_area_ratio: float = Field(
        0.25, ge=0.0, le=1.0, description="Minimum blob area / projected area of the part's estimate for re-seeding "
        "(a sliver of a hidden part gives a biased centroid).",
    )
    far_sliver_radii: float = Field(
        1.5, ge=0.0, description="A confident blob smaller than reseed_min_area_ratio of the part still re-seeds it "
        "when its centroid lies more than this many projected bounding radii from the estimate (0 = off).",
    )
    blob_follow: bool = Field(
        False, description="Blob follow (not in the spec; filter/blob_follow.py): a part whose confident colour blob "
        "has little valid depth moves with the blob's centroid between frames in which the blob keeps its area; its "
        "rest and support priors are off meanwhile.",
    )
    blob_follow_max_area_change: float = Field(
        0.25, gt=0.0, description="Largest relative change of the blob's area between two frames for blob follow.",
    )
    blob_follow_max_depth_fraction: float = Field(
        0.2, ge=0.0, le=1.0, description="Blob follow applies while fewer than this fraction of the blob's pixels "
        "have valid depth.",
    )
    blob_follow_min_px: float = Field(
        1.0, ge=0.0, description="Smallest centroid motion (pixels) blob follow applies.",
    )
    blob_follow_overlap: bool = Field(
        False, description="Blob follow moves a part only when the blob's outline shows the motion: last frame's "
        "outline moved by the centroid's shift covers more of this frame's blob than unmoved. A blob that only "
        "shrank (a hand coming over a resting part) is not followed.",
    )
    blob_follow_inside_px: float = Field(
        0.0, ge=0.0, description="Pixels (0 = off): blob follow does not move a part that is not carried while its "
        "blob's bounding box lies inside the part's projected bounding rectangle at its estimate grown by this "
        "margin: a blob that shrinks or shifts within the part's own footprint is a hand or part coming over a "
        "resting part (its centroid moves away from the occluder), not the part moving; a part that moves leaves "
        "its footprint.",
    )
    blob_follow_inside_covered: bool = Field(
        False, description="With blob_follow_inside_px: a blob inside the part's footprint stops blob follow only "
        "while the depth over the footprint is covered (nearer than the part's surface over at least half of it, no "
        "table showing; filter/footprint_depth.py): a hand over it. A part the depth still shows, or whose place shows "
        "the table, is followed.",
    )
    blob_follow_keep_anchor: bool = Field(
        False, description="Blob follow moves a part that is not carried without its rest anchor: a hand coming over "
        "a resting part drags its shrinking blob's centroid, and a moved anchor would then hold the hidden part where "
        "the drag left it; a part that truly leaves is carried (and a carry sets the anchor, carry_anchor_start) or "
        "placed by the depth again.",
    )
    scene_motion: bool = Field(
        False, description="Scene motion (not in the spec; filter/scene_motion.py): parts that the depth did not place "
        "this frame (hidden, or seen in colour without depth) and that are neither carried nor moving with their blob "
        "follow the camera motion that the well-seen resting parts agree on.",
    )
    carry_motion_scene: bool = Field(
        False, description="Scene motion: the hand-carry motion test (carry_min_motion in carry_window_s) measures a "
        "part's travel against the scene: when the well-seen resting parts agree on a camera motion, the remembered "
        "positions of every part are moved by it, so that a hand-held or swaying camera's own motion (1-2 mm a "
        "frame, 15 mm in the test's window) does not make a hidden resting part count as moving and be taken along "
        "by a hand passing over it.",
    )
    scene_motion_keyframe: bool = Field(
        False, description="Scene motion: a part unplaced for several frames is moved by the landmarks' motion since "
        "the frame it was last placed (its keyframe), not by chained frame-to-frame motions.",
    )
    scene_motion_tolerance: float = Field(
        0.003, gt=0.0, description="Metres: landmarks agree with a camera motion when it moves their centre within "
        "this distance of their own motion (and turns them by less than tolerance / 0.05 rad from it).",
    )
    scene_motion_min_anchors: int = Field(2, ge=1, description="Fewest agreeing landmarks for a scene motion.")
    scene_motion_spread: float = Field(
        0.0, ge=0.0, description="Metres: 0 = the landmarks' consensus motion turns by the mean of their own turns; "
        "> 0 = the least-squares rigid motion of points this far around each landmark's centre, each moved by the "
        "landmark's own motion (a part's turn jitter counts with its size, the landmarks' spread with theirs).",
    )
    scene_motion_deadband: float = Field(
        0.0003, ge=0.0, description="Metres: smaller motions of a hidden part's centre are not applied.",
    )
    detected_full_noise: bool = Field(
        False, description="A part with a reliable colour detection (reseed_min_score/area) always gets its full "
        "motion noise, whatever its estimated visible fraction (hidden_noise_scale damps hidden parts only).",
    )

    # --- occlusion dynamics (spec 4.8)
    p_occ_given_vis: float = Field(
        0.1, ge=0.0, le=1.0, description="p(o=1|o=0) as a rate per second (reference default 0.1)."
    )
    p_occ_given_occ: float = Field(
        0.7, ge=0.0, le=1.0, description="p(o=1|o=1) as a rate per second (reference default 0.7)."
    )
    initial_occlusion: float = Field(0.1, ge=0.0, le=1.0, description="o_0, initial occlusion probability.")
    use_occlusion_model: bool = Field(
        True, description="Ablation switch: False = every pixel visible (o = 0), no occlusion posterior."
    )

    # --- depth observation model (spec 4.9, 4.10)
    tail_weight: float = Field(0.01, ge=0.0, lt=1.0, description="beta, weight of the uniform heavy tail.")
    sigma_model: float = Field(0.003, ge=0.0, description="Constant term of sigma(z) = sigma_model + factor z^2, m.")
    sigma_factor: float = Field(0.00142478, ge=0.0, description="Quadratic term of sigma(z), 1/m.")
    half_life_depth: float = Field(1.0, gt=0.0, description="Occluder depth half life, m; lambda = ln2 / this.")
    max_depth: float = Field(6.0, gt=0.0, description="m, maximum sensor depth, metres.")
    downsample: int = Field(8, ge=1, le=16, description="Likelihood resolution: depth image subsampled by this.")
    likelihood_exponent: float = Field(
        1.0, gt=0.0, le=1.0, description="alpha: each pixel's likelihood ratio is raised to this power (1 = the "
        "spec's independent pixels; < 1 tempers the product for correlated sensor noise). Not in the spec.",
    )
    occluded_evidence_cap: float = Field(
        0.0, ge=0.0, description="Where a particle's part lies more than this many sigma(z) behind the observed "
        "depth, the pixel's log-likelihood ratio is capped at 0: occlusion is no evidence for a pose (the spec's "
        "truncated occluder density 1/(1 - exp(-lambda d)) otherwise pulls hidden parts toward the camera, into a "
        "hand). 0 = the spec.",
    )
    likelihood_pixels_per_part: int = Field(
        0, ge=0, description="Most likelihood pixels (downsampled grid) per part and frame; a part covering more is "
        "evaluated on an even subset of them (0 = all). Bounds the cost of large parts; not in the spec.",
    )
    roi_margin_px: int = Field(
        2, ge=0, description="Margin (downsampled pixels) around the parts' projections that is evaluated."
    )

    # --- ICP refinement (spec section 17, future work; not in the seed)
    icp_refinement: bool = Field(
        False, description="Refine well-visible parts with point-to-plane ICP on their full-resolution points (colour "
        "blob, or near the estimate above the table) and shift their particles by the correction.",
    )
    icp_min_visibility: float = Field(0.85, ge=0.0, le=1.0, description="Visible fraction needed for refinement.")
    icp_iterations: int = Field(6, ge=1, description="ICP iterations per part and frame.")
    icp_stride: int = Field(3, ge=1, description="Use every n-th full-resolution pixel (each axis) for ICP.")
    icp_max_translation: float = Field(0.008, gt=0.0, description="Largest accepted ICP correction, metres.")
    icp_max_rotation: float = Field(0.15, gt=0.0, description="Largest accepted ICP rotation correction, radians.")
    icp_reuse_px: float = Field(
        0.0, ge=0.0, description="Reuse a part's last ICP result instead of running ICP again while its colour blob "
        "stays put (centroid within this many pixels, area within 5 % of the refined frame's); 0 = refine every "
        "frame. Parts without colour always run ICP.",
    )
    icp_max_skipped: int = Field(3, ge=0, description="With icp_reuse_px: run ICP at least every (this + 1)-th frame.")

    # --- dense-depth refinement (spec depth-refinement.md; tracker/refine/dense_depth.py)
    dense_refinement: bool = Field(
        False, description="After the filter, refine every visible part by robust point-to-plane Gauss-Newton on the "
        "full-resolution depth at its rendered silhouette (occlusion-aware: pixels of parts in front, outside the "
        "part's colour blob or far in front of the model are left out) and move its particles with the correction. "
        "Replaces icp_refinement when both are on.",
    )
    refine_stride: int = Field(2, ge=1, description="Pixel stride of the rendered model points (full resolution).")
    refine_max_points: int = Field(600, ge=20, description="Model points per part and frame (thinned evenly).")
    refine_thresholds: tuple[float, ...] = Field(
        (0.03, 0.015, 0.008, 0.005), min_length=1,
        description="Largest accepted model-to-measurement distance (m) per correspondence iteration.",
    )
    refine_updates: int = Field(2, ge=1, description="Gauss-Newton updates per correspondence iteration.")
    refine_converged_step: float = Field(
        0.0, ge=0.0, description="End a part's Gauss-Newton iterations, the finer thresholds' too, once an update's "
        "norm (rad and m together) falls below this: its pose has converged (a speed setting; 0 = all thresholds "
        "run; 5e-5 saved no measurable CPU on the tuning seeds, session 18).",
    )
    refine_converged_rotation: float = Field(
        0.0, ge=0.0, description="With refine_converged_translation: end a part's Gauss-Newton iterations, the finer "
        "thresholds' too, once an update after the coarsest threshold turns it by less than this (rad) and moves its "
        "centre by less than refine_converged_translation (m): the updates after the first few circle at 0.01-0.1 deg "
        "and mm instead of vanishing (a speed setting; 0 = all thresholds run; 0.001745 rad / 5e-5 m: -1.6 ms a "
        "7-cube frame, worse on tuning set 2, session 29).",
    )
    refine_converged_translation: float = Field(
        0.0, ge=0.0, description="See refine_converged_rotation (m).",
    )
    refine_outline_per_threshold: bool = Field(
        False, description="The silhouette term's outline (taken at pixel positions) is re-extracted at the first "
        "update of each correspondence threshold only, not at every update (which makes its cost piecewise constant "
        "in the pose).",
    )
    refine_bilinear_m: float = Field(
        0.0, ge=0.0, description="> 0: the refinement reads each model point's measured depth bilinearly at its "
        "sub-pixel projection (its four neighbouring pixels, when all have depth and span less than this, m; else the "
        "nearest pixel), its measured point on the model point's viewing ray, so that the cost changes continuously "
        "with the pose instead of in the depth's 1 mm steps (0 = nearest pixel).",
    )
    refine_occlusion: float = Field(
        0.03, gt=0.0, description="A measurement this far (m) in front of a model point means it is occluded.",
    )
    refine_lambda_rot: float = Field(25.0, ge=0.0, description="Tikhonov weight on each rotation update, 1/rad^2.")
    refine_lambda_trans: float = Field(2500.0, ge=0.0, description="Tikhonov weight on each translation update, 1/m^2.")
    refine_few_points_position: bool = Field(
        False, description="A partly hidden part whose refinement matched most of its observable model points but "
        "fewer than twice the minimum (25) is refined again with its rotation held and moved to that position (its "
        "rotation kept): such refinements put the centre within 1-2 mm but turned it 3-12 deg on the tuning traces, "
        "and were rejected whole (tracker/refine/dense_depth.py). Off: better on both tuning sets (session 20), "
        "but five seeded carry tests fail with it on.",
    )
    refine_min_valid_fraction: float = Field(
        0.35, ge=0.0, le=1.0, description="Share of visible model points that must find a valid depth pair for the "
        "refinement to count as healthy (else the filter's estimate is kept).",
    )
    # --- speed settings that change results (filter/quiet_parts.py; off in the seed presets)
    quiet_skip: bool = Field(
        False, description="Skip the coordinate pass of a quiet part: well visible, not carried or touched, its colour "
        "blob of about the same area and moved as its prediction says, and last frame's refinement correction small "
        "(filter/quiet_parts.py). It keeps its noise-free prediction; the refinement holds it to the depth. Off by "
        "default: 2-6 ms less per 7-cube frame, but more carried parts lost on the tuning seeds; with "
        "quiet_max_residual_m 0.005 not worse on the tuning seeds in session 17, but in session 18 (after "
        "carry_keep_moving) set 1 lost 0 -> 2 parts (benchmarks/history/issue-11-speed.md).",
    )
    quiet_max_px: float = Field(
        1.5, ge=0.0, description="Largest difference (pixels) between the blob centroid's image motion and the "
        "prediction's for a quiet part.",
    )
    quiet_max_area_change: float = Field(
        0.1, ge=0.0, description="Largest relative change of the blob's area between two frames for a quiet part.",
    )
    quiet_max_correction_m: float = Field(
        0.002, ge=0.0, description="Largest last-frame refinement correction (m, at the part's centre) of a quiet "
        "part.",
    )
    quiet_max_correction_deg: float = Field(
        2.0, ge=0.0, description="Largest last-frame refinement rotation correction (degrees) of a quiet part.",
    )
    quiet_pixels_per_part: int = Field(
        0, ge=0, description="Likelihood pixel budget of a quiet part (quiet_skip), in place of "
        "likelihood_pixels_per_part: it is evaluated only at its prediction (0 = the same budget).",
    )
    quiet_keep_spread: bool = Field(
        False, description="A quiet part's particles still get the frame's motion noise (after the weighing), so that "
        "its cloud keeps its spread while its passes are skipped.",
    )
    quiet_max_skips: int = Field(
        3, ge=0, description="Passes a quiet part may skip in a row; the next one runs (its particles re-spread).",
    )
    quiet_thin: bool = Field(
        False, description="A quiet part (the tests of quiet_skip) keeps its coordinate pass, but its likelihood is "
        "evaluated on quiet_pixels_per_part pixels (filter/quiet_parts.py): its particles keep their noise and "
        "resampling, so its cloud keeps its spread for when a hand takes it (what quiet_skip lost). Speed setting, "
        "off: with quiet_pixels_per_part 60 it lost a part on tuning set 1 (session 19, README).",
    )
    quiet_refine_last: int = Field(
        0, ge=0, description="A quiet part is refined with only the last (finest) this many correspondence thresholds "
        "of refine_thresholds (0 = all): its last correction was small and the depth shows it at its prediction. "
        "Speed setting, off (2: about 0.2 ms less per quiet part; lost a part on tuning set 1, session 19).",
    )
    quiet_converged_rotation: float = Field(
        0.0, ge=0.0, description="With quiet_converged_translation: a quiet part (the tests of quiet_skip) ends its "
        "Gauss-Newton iterations, the finer thresholds' too, at the first update after the coarsest threshold that "
        "turns it by less than this (rad) and moves its centre by less than quiet_converged_translation (m): "
        "refine_converged_rotation for quiet parts only (its last correction was small and it is well seen, not "
        "carried or touched; carries keep every update). Speed setting, off (0 = every threshold runs): 0.001745 rad / "
        "5e-5 m saved 0.74 ms a 7-cube frame but was worse on tuning sets 1 and 2 (400 -> 416, 499 -> 622 bad "
        "part-frames, session 33).",
    )
    quiet_converged_translation: float = Field(
        0.0, ge=0.0, description="See quiet_converged_rotation (m).",
    )
    quiet_refine_skip: bool = Field(
        False, description="A quiet part is not refined this frame: it keeps the filter's estimate (no loss count, no "
        "re-acquisition, no table fit). Having no correction to remember, it is not quiet the next frame, so it is "
        "refined at least every other frame. Speed setting, off: with quiet_refine_hold worse on tuning set 1 "
        "(session 19: a held part lags a swaying camera; README).",
    )
    quiet_refine_hold: bool = Field(
        False, description="With quiet_refine_skip: a quiet part is held at its noise-free prediction's mean pose "
        "(its particles moved there, as a refinement's correction moves them) instead of keeping the filter's "
        "estimate of the frame.",
    )
    quiet_refine_hold_last: bool = Field(
        False, description="With quiet_refine_skip and quiet_refine_hold: a quiet part is held at its last estimate "
        "(moved with the camera by the odometry) instead of its constant-velocity prediction: it rests. Speed setting, "
        "off: with the other two and quiet_max_residual_m 0.005 better on tuning sets 1 and 2, worse on set 3 "
        "(session 22, README), and 11 carry tests fail with them on by default.",
    )
    quiet_skip_held: bool = Field(
        False, description="With quiet_skip and quiet_refine_skip: a part held this frame (its refinement skipped) "
        "stays quiet for next frame's coordinate pass (the small correction it was held on is remembered until its "
        "next refinement): its pass is skipped on every quiet frame (up to quiet_max_skips in a row) and it is refined "
        "every other frame (without it the pass is skipped only on the frames it is held). Speed setting, off.",
    )
    quiet_max_residual_m: float = Field(
        0.0, ge=0.0, description="With quiet_skip: a quiet part's depth must also be explained at its prediction "
        "this frame: of the sample points on its camera-facing box faces (last estimate moved by the prediction) at "
        "least quiet_min_inliers of those with depth lie within this distance (m) of the measured depth, a hand or "
        "a part in front counting against it (filter/quiet_parts.py: depth_explained). 0 = no depth test.",
    )
    quiet_min_inliers: float = Field(
        0.85, ge=0.0, le=1.0, description="Share of a quiet part's face points with depth that must lie within "
        "quiet_max_residual_m of the measured depth (and at least half of them must have depth).",
    )
    reacquire: bool = Field(
        True, description="Re-acquire a part (several refinements from rotations around its estimate, the best "
        "supported by the depth wins) when it is lost, right after a hand releases it and when it reappears; needs "
        "dense_refinement.",
    )
    loss_bad_frames: int = Field(
        3, ge=1, description="Frames in a row without a healthy refinement, while the part should be visible, after "
        "which it is re-acquired from several starting rotations (tracker/refine/recovery.py).",
    )
    reacquire_cooldown: int = Field(5, ge=1, description="Fewest frames between two re-acquisitions of a part.")
    reacquire_tilt_gain: float = Field(
        0.25, ge=0.0, description="Re-acquisition of a box part with a table: a candidate whose refined rotation is "
        "tilted more than 15 deg off lying flat on the table replaces the estimate only when its score also beats the "
        "best candidate within 15 deg of flat (the estimate's own refinement included) by this fraction of that "
        "one's score plus the usual margin: a sliver of a mostly hidden part fits a tilted face by a few points more, "
        "while a start that lays a carry-tilted part flat again keeps the usual margin (0 = off: the usual margin "
        "only; tracker/refine/recovery.py).",
    )
    carry_release_on_lift: int = Field(
        0, ge=0, description="A carried part set down (carried in the air, then with its lowest point within "
        "carry_min_height of the table for at least this many frames in a row) is let go, not lifted, when the hand "
        "then rises from the table by more than carry_lift_m in a frame (0 = off): hands leave the parts they put "
        "down. "
        "(A part picked up again is missed where it was and found by the see-through test.)",
    )
    carry_above_table: bool = Field(
        False, description="A carried part the hand's motion takes below the table top is moved up onto it.",
    )
    carry_lift_m: float = Field(0.003, gt=0.0, description="Rise (m) of the hand in one frame that lets go of a part "
                                "set down (carry_release_on_lift, carry_set_down_m).")
    carry_set_down_m: float = Field(
        0.0, ge=0.0, description="A carried part that has been in the air is put down when the hand then stands still "
        "for two frames with the part's lowest point within this many metres of the table: it is moved onto the table "
        "and held there (not moved with the hand) until the hand rises by more than carry_lift_m in a frame (let go) "
        "or moves on along the table by more than carry_set_down_slide_m (taken along). 0 = off "
        "(filter/hidden_parts.py: held_where_put).",
    )
    carry_set_down_on_parts: bool = Field(
        False, description="carry_set_down_m also puts a part down on top of a part below it (its height counted from "
        "that part's top, filter/hidden_parts.py: surface_below), not only on the table.",
    )
    carry_set_down_slide_m: float = Field(
        0.02, gt=0.0, description="Motion (m) along the table of the hand since it put a part down (carry_set_down_m) "
        "after which the part moves with the hand again.",
    )
    refine_region_weight: float = Field(
        0.0, ge=0.0, description="Weight of the silhouette term of the refinement (the rendered outline on the colour "
        "blob's edge, refine/region_term.py); 0 = depth only.",
    )
    refine_region_depth_agree: float = Field(
        0.0, ge=0.0, description="Silhouette term: a rendered outline point outside the colour blob whose measured "
        "depth lies within this many metres of the point's own is not paired (the depth shows the part there; the "
        "blob left out a shaded face, which would turn the part). 0 = off.",
    )
    refine_region_normal_cos: float = Field(
        0.0, ge=0.0, le=1.0, description="Silhouette term: a rendered outline point is paired with the colour blob's "
        "edge only where that edge faces the outline's own way (cosine of the blob's outward gradient and the "
        "rendered silhouette's outward normal at least this; a cube's shaded side the blob left out otherwise pulls "
        "towards another edge of the blob and turns the part). 0 = off (session 18: 0.5 holds a cube under another "
        "at the truth where it went 10° and 4 mm off on tuning seed 4 of guess-1, paired on both tuning sets 652 -> "
        "643 and 875 -> 871 bad part-frames, lost 0 -> 0 and 2 -> 1, but 6 hand-carry tests of partly seen carried "
        "cubes fail with it: not the default yet).",
    )
    refine_region_lines: float = Field(
        0.0, ge=0.0, description="Silhouette term, correspondence lines (ICG/M3T), tolerance in px: each rendered "
        "outline point's colour-blob edge is also searched along the outline's own outward normal (the nearest "
        "crossing from inside to outside within the term's reach; none: not paired); where the residual it gives "
        "differs from the blob's signed distance (the nearest edge, which may lie at right angles to the outline) by "
        "more than this, the point is paired along its normal (refine/region_term.py `_line_edge`); a paired edge "
        "with a nearer measurement just beyond it is an occluder's and is dropped. 0 = off (session 19, 1.0 paired "
        "with fused odometry: set 1 631 -> 678, set 2 789 -> 730 bad part-frames, lost 0 -> 0 on both; tuning seed 4 "
        "of guess-1 38 -> 14; +12 % tracker CPU: not the default).",
    )
    table_silhouette: bool = Field(
        False, description="A resting part seen in colour but not placed by the depth (a hand's projector shadow) is "
        "placed on the table from its colour blob's outline (refine/table_silhouette.py).",
    )
    table_silhouette_max_height: float = Field(
        0.006, gt=0.0, description="Table silhouette: largest height (m) of a part's lowest corner above or below the "
        "table for it to count as resting.")
    table_silhouette_max_tilt_deg: float = Field(
        10.0, gt=0.0, le=45.0,
        description="Table silhouette: largest tilt (degrees) of a resting part's face from flat.")
    table_silhouette_min_iou: float = Field(
        0.7, ge=0.0, le=1.0, description="Table silhouette: smallest intersection over union (and share of the blob "
        "inside) of the fitted expected silhouette and the blob for the fit to be taken.")
    table_silhouette_max_step: float = Field(
        0.015, gt=0.0, description="Table silhouette: largest move (m) of the part's centre taken in one frame.")
    table_silhouette_max_turn_deg: float = Field(
        15.0, gt=0.0, description="Table silhouette: largest turn (degrees) taken in one frame.")
    table_silhouette_snap: bool = Field(
        True, description="Table silhouette: move the part along the table's normal onto it before the fit.")
    table_silhouette_turn: bool = Field(
        True, description="Table silhouette: fit the turn about the table's normal as well as the shift (else the "
        "part keeps the rotation its depth last gave it).")
    table_silhouette_turn_coverage: float = Field(
        0.0, ge=0.0, le=1.0, description="Table silhouette: a blob covering less than this share of the part's whole "
        "silhouette only shifts it (no turn); 0 = always turn too.")
    table_silhouette_iterations: int = Field(8, ge=1, description="Table silhouette: Gauss-Newton updates per frame.")
    refine_max_translation: float = Field(0.03, gt=0.0, description="Largest accepted refinement correction, metres.")
    refine_max_rotation: float = Field(0.35, gt=0.0, description="Largest accepted refinement rotation, radians.")

    # --- penalties (spec 4.13-4.15)
    lambda_i: float = Field(0.01, gt=0.0, le=1.0, description="Intersection penalty factor lambda_i (not 0).")
    contact_tolerance: float = Field(
        0.002, ge=0.0, description="Penetration depth (m) two parts may have before they count as intersecting."
    )
    lambda_h: float = Field(1000.0, ge=0.0, description="Table-sinking penalty rate lambda_h, 1/m.")
    table_tolerance: float = Field(
        0.0, ge=0.0, description="Depth (m) below the table plane a vertex may reach without penalty."
    )
    use_intersection_penalty: bool = Field(True, description="Ablation switch for the intersection penalty.")
    use_table_penalty: bool = Field(True, description="Ablation switch for the table-sinking penalty.")
    use_color_input: bool = Field(True, description="Ablation switch for the colour control input u.")

    # --- connection particles (spec 9, 10); m_p, K, N_max, N_checks are used by the assembly monitor
    use_connection_particles: bool = Field(True, description="Ablation switch for Algorithm 6.")
    max_connection_fraction: float = Field(
        0.5, ge=0.0, le=1.0, description="Overflow rule: N_k is clipped to this fraction of N (rest stay free)."
    )
    hint_min_visibility: float = Field(
        0.5, ge=0.0, le=1.0,
        description="A connection hint that is not locked forces a part only while the part's estimated visible "
        "fraction (previous frame) is at least this and, when colour detections are given, it has a reliable colour "
        "blob in the current frame (a hidden cube, e.g. in the hand, cannot be judged by the depth image and "
        "would jump onto its neighbour); locked connections always apply. 0 = off.",
    )
    m_p: float = Field(0.01, gt=0.0, description="Position margin m_p of the connection score (5.16), metres.")
    score_k: float = Field(3.0, ge=0.0, description="Score sensitivity K of (5.16).")
    n_max: int = Field(9, ge=0, description="N_max, maximum particles per connection (5.19).")
    n_checks: int = Field(2, ge=1, description="N_checks, consecutive frames for a connection.")

    # --- misc
    frame_dt: float = Field(1.0 / 30.0, gt=0.0, description="Frame interval (s) assumed when timestamps are absent.")

    @property
    def occluder_rate(self) -> float:
        """lambda = ln 2 / half_life_depth, 1/m."""
        return math.log(2.0) / self.half_life_depth

    # ------------------------------------------------------------------ presets and files
    @staticmethod
    def preset(name: str) -> TrackerConfig:
        """A named preset: ``"seed-exp1"``, ``"seed-exp23"`` or ``"default"``."""
        if name not in PRESETS:
            raise ValueError(f"unknown tracker preset {name!r}; choose one of {sorted(PRESETS)}")
        return TrackerConfig(**PRESETS[name])

    def with_overrides(self, **overrides: Any) -> TrackerConfig:
        """A copy with some fields replaced (validated)."""
        data = self.model_dump()
        data.update(overrides)
        try:
            return TrackerConfig(**data)
        except ValidationError as exc:
            raise ValueError(f"invalid tracker setting: {exc}") from exc

    @staticmethod
    def load(path: str | Path, preset: str | None = None) -> TrackerConfig:
        """Settings from a YAML (``.yaml``/``.yml``) or TOML (``.toml``) file over a preset.

        The file holds ``field: value`` pairs (optionally under a top-level ``tracker`` key) and may name its
        base preset with ``preset: NAME``; the ``preset`` argument wins over the file's key.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"tracker config file not found: {path}")
        text = path.read_text()
        try:
            if path.suffix.lower() == ".toml":
                data = tomllib.loads(text)
            elif path.suffix.lower() in (".yaml", ".yml"):
                data = yaml.safe_load(text) or {}
            else:
                raise ValueError(f"tracker config {path}: use a .yaml, .yml or .toml file")
        except (tomllib.TOMLDecodeError, yaml.YAMLError) as exc:
            raise ValueError(f"tracker config {path}: cannot parse: {exc}") from exc
        if not isinstance(data, dict):
            raise ValueError(f"tracker config {path}: expected a mapping of settings")
        if isinstance(data.get("tracker"), dict):
            data = data["tracker"]
        data = dict(data)
        base = preset or data.pop("preset", None) or "default"
        data.pop("preset", None)
        unknown = sorted(set(data) - set(TrackerConfig.model_fields))
        if unknown:
            raise ValueError(f"tracker config {path}: unknown setting(s) {unknown}")
        try:
            return TrackerConfig.preset(base).with_overrides(**data)
        except ValueError as exc:
            raise ValueError(f"tracker config {path}: {exc}") from exc


_SEED_COMMON: dict[str, Any] = {
    "n_particles": 225,
    "lambda_i": 0.01,
    "lambda_h": 1000.0,
    "lambda_z": 1.0,
    "downsample": 8,
    "table_tolerance": 0.0,
}

PRESETS: dict[str, dict[str, Any]] = {
    "seed-exp1": {
        **_SEED_COMMON,
        "b": 0.5,
        "k_v": 0.3,
        "sigma_v": 0.01,
        "sigma_w": 0.1,
        "m_p": 0.04,
        "kl_max": 0.5,
        "score_k": 7.0,
        "n_max": 12,
        "n_checks": 4,
    },
    "seed-exp23": {
        **_SEED_COMMON,
        "b": 0.3,
        "k_v": 0.2,
        "sigma_v": 0.005,
        "sigma_w": 0.05,
        "m_p": 0.01,
        "kl_max": 1.0,
        "score_k": 3.0,
        "n_max": 9,
        "n_checks": 2,
    },
}
PRESETS["default"] = {
    **PRESETS["seed-exp23"],
    # tuned on simulated static / guess-* / learning-5 sequences (benchmarks/bench_tracker.py); 1/5 resolution
    # (ICP refinement restores the precision) keeps 5 cubes under 33 ms per frame on one core
    "downsample": 5,
    "likelihood_exponent": 0.15,
    "sigma_v": 0.0015,
    "sigma_w": 0.006,
    "wide_noise_fraction": 0.15,
    "wide_noise_scale": 10.0,
    "hidden_noise_scale": 0.1,
    "table_tolerance": 0.001,
    "color_mask_likelihood": True,
    "color_mask_when_missing": True,
    "color_likelihood_px": 10.0,
    "dense_refinement": True,
    "refine_region_weight": 1.0,
    "refine_region_depth_agree": 0.008,
    "likelihood_pixels_per_part": 250,
    "reseed_fraction": 0.3,
    "detected_full_noise": True,
    "color_term_dead_zone": 1.0,
    "occluded_evidence_cap": 3.0,
    "rest_prior_sigma": 0.003,
    "rest_prior_rotation": True,
    "rest_anchor_moving": True,
    "color_visible_centroid": True,
    "carry_turn_fallback": True,
    "carry_start_register": True,
    "carry_follow": True,
    "support_prior_sigma": 0.003,
    "blob_follow": True,
    "contact_align_deg": 20.0,
    "scene_motion": True,
    "carry_revealed_fraction": 0.5,
    "revealed_surface": True,
    "carry_shadow": True,
    "carry_max_step": 0.05,
    "table_upright": True,
    "carry_release_on_lift": 3,
    "carry_above_table": True,
    "carry_keep_unseen": 0.3,
    "carry_anchor_start": True,
    "carry_keep_moving": 0.005,
    "carry_left_table": 0.2,
    "blob_follow_inside_px": 3.0,
    "blob_follow_inside_covered": True,
    "carry_backtrack": 3,
    "carry_set_down_m": 0.02,
    "carry_set_down_on_parts": True,
    "carry_upright_air": True,
    "carry_over_sliver": True,
    "carry_sliver_particles": True,
    "carry_lift_lookback": True,
}
"""Preset name -> field values. Seed presets: spec section 15; "default": this product's tuned values."""
