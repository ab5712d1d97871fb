"""``HandTracker``: follows up to two hands in a colour stream (hand-tracking spec §14.3–14.4).

Per frame (:meth:`HandTracker.process`): the ROI around all tracks' particles (§14.2: each box expanded by
m_ROI = max(24 px, 0.5·max(w, h), 2‖v‖), clipped), the colour masks of frames k−1 and k inside it, the four flows
and motion segmentations (:mod:`tracker.hands.features`), one filter step per track (particle filter or Kalman
reference; the palm anchors of :mod:`tracker.hands.palm_cut` extend the section-6 mode to bare forearms), track
termination, track identity (:mod:`tracker.hands.identity`), then re-acquisition of lost tracks and automatic
initialisation of new tracks:

* Candidates (§14.3): 4-connected components of the colour mask after an opening (disk radius 2 px),
  computed at the working resolution over the whole frame (radius 2/scale there), with area ≥ A_min = 0.15 % of
  the image, no pixel inside an existing track's box (spec: at most 50 %; a hand that enters grows faster than
  its new track's box, which made a second track on it), seen on n_init = 3 consecutive frames (matched by
  overlapping boxes). A candidate must touch the image border (within b = 2 px) when first seen; product
  deviation: it need not touch it on the next two frames (a long-sleeved hand's skin touches the border only
  briefly while it enters). The largest one starts a track; at most one new track per frame, at most
  ``max_tracks`` tracks, live and lost together.
* Initial box: the component's pixels farther than d_max − L_hand from its entry point e (mean of its border
  pixels), L_hand = f_x · ``hand_length_m`` / Z̄ (Z̄ the median depth of the component's far end; without depth
  Z̄ = 0.75 m), their tight box, velocity 0 (:func:`tracker.hands.palm_cut.palm_cut`); the whole component if it is
  no longer than a hand (a sleeve: no forearm in it). With ``palm_tube`` (default) an arm's palm is cut by the
  forearm tube instead (:func:`tracker.hands.palm_cut.tube_cut`), for the initial box and the anchors alike.
* Termination: < 50 % of the estimate's box inside the image; a_{c,1} of the estimate < 0.2 for 10 consecutive
  frames; two tracks with box F-score ≥ 0.8 for 10 consecutive frames (product change: the one whose appearance
  fits the shared box worse ends, the younger on a tie); product addition: the box smaller than A_min for 10
  consecutive frames (a lost track otherwise shrinks onto a speck of skin colour); product addition
  (:data:`EXIT_END`, session 32): a box that reaches the image border (within b) with no colour pixel in it ends at
  once — its hand has left the image (before, such a track stayed on the border as a thin box, scored a false box,
  until the other rules ended it 4–9 frames later).
* Two hands on top of each other (product addition): if both tracks of such a duplicate had each spent
  ESTABLISHED frames apart (box F-score < APART_F with every other track), they are two hands that overlap, not two
  tracks on one hand: both stay, "merged", for up to MERGED_KEEP frames, their appearance models frozen; if a skin
  region no track explains turns up meanwhile (a candidate as for re-acquisition), the track whose appearance fits
  it better (else the one whose box lies more inside the other's, then the younger) restarts there with its id; the
  same when two tracks' boxes share a region (SHARED_FRAC) without being merged. A track that lands within one step
  on the box of a track it was apart from the frame before (a jump onto the other hand's colour component) is put
  back and moved by its own velocity instead. Merged tracks are kept past MERGED_KEEP while the arm detector's last
  run gave each its own arm (``ARM_KEEP_MERGED``, on, session 24; ``arm_anchor`` below): traced on ``hands-s2``
  tuning seed 3 (ground-truth start, filter seed 0), the two filters shared one box for 120 frames while each track
  reported its own arm's hand, then hand 0's track ended (frames 164–212 without a box, the other track's box over
  both hands, as the arm detector runs only with two tracks). Tuning seeds 0–4, same frames (scratch script), off →
  on: ground-truth start filter seed 0 F̄^b 0.8547 → 0.8699, ē^p 8.42 → 8.19 px (seed 3 0.8205 → 0.8966, the other
  four identical); filter seeds 1, 2 identical (no merge lasts 120 frames); automatic start (filter seed 0)
  identical; ``hands-s1`` (automatic start, seeds 0, 1) and ``hands-s3`` (automatic start seeds 0–2, ground truth
  seeds 3, 4) identical.
* A lost hand inside the other hand's colour component (product addition, ``merge_reacquire``): while a lost track
  waits and the one live track's box has grown to REACQ_GROWTH times its one-hand area (the two hands on top of each
  other, one box over both), the component under that box is split by 2-means on pixel positions and the lost track
  restarts on the part away from the live track (:meth:`HandTracker._reacquire_from_merge`). Tuning seeds 0–4 of
  ``hands-s2``, automatic start: missed hands 10.6 % → 3.9 % (seed 4: 28 % → 1.8 %), false boxes 0.045 → 0.049 per
  frame.
* Two touching hands under one grown box (product addition, ``shared_split``): when one track's box has grown over
  both hands of one colour component and the other track sits inside it (the hand that came out from under the
  other is covered by the top hand's track, and its own track stayed on the top hand), the component is split by
  2-means and each track restarts on its part, the grown one on the part nearer the centre it had at one-hand size
  (:meth:`HandTracker._split_shared`). Tuning seeds 0–4 of ``hands-s2``, ground-truth start, mean F̄^b 0.672 →
  0.692 (seed 2 0.60 → 0.69); automatic start and S1, S3 unchanged within ±0.01.
* Each hand's own skin pixels through an overlap (product addition, ``ownership``, off by default): an owner map of
  the skin pixels, carried from frame to frame by the backward optical flow, gives each track, while the two hands
  touch, the colour components without the other hand's pixels for its section-6 mode and re-seeding
  (:mod:`tracker.hands.ownership`). Tuning seeds 0–4 of ``hands-s2``, ground-truth start, four filter seeds: mean
  F̄^b 0.678 → 0.714, but not on every sequence (seeds 1 and 3 0.76 → 0.85 and 0.69 → 0.91; seeds 0 and 4 0.78 →
  0.74 and 0.61 → 0.53: an identity swap that the owner map then keeps); automatic start F̄^b 0.80 → 0.84, missed
  hands 3.1 → 3.6 %, false boxes 0.034 → 0.043 per frame. Off because the gain is not consistent: on the held-out
  seeds 100, 101 it gave F̄^b 0.574 against 0.683 (benchmarks/results/hands_s13_ownership.md).
* Two hands in one colour component (product addition, ``split_blobs``, off by default): when the two tracks'
  predicted boxes share their dominant colour component, too large for one hand (SPLIT_HAND_M) and clearly larger
  than either box, its pixels are split between the two tracks by nearness to their predicted centres before the
  filter steps (:mod:`tracker.hands.blob_split`), so that neither box grows over both hands. Off because it trades
  automatic start for ground-truth start: on the tuning seeds of ``hands-s2`` it raises F̄^b with ground-truth start
  (0.68 → 0.74) but with automatic start two tracks that share one hand are kept apart instead of ending as
  duplicates (false boxes 0.05 → 0.13 per frame, missed hands 3.9 % → 10.4 %).
* Coasting (product addition, ``coast``, off by default): a track whose hand disappears under something near
  another track (the other hand's arm) moves on its velocity instead of following the shrinking visible part
  (:meth:`HandTracker._covered`). Off because on the tuning seeds of ``hands-s2`` it cost more than it gained
  (mean F̄^b over seeds 0–4 with ground-truth start: 0.72 → 0.69 with the blob split, 0.69 → 0.70 without; a
  coasting track's prediction can leave the next shared component unsplit).
* Which part is whose by depth (product addition, ``depth_identity``, off by default): each track remembers the
  median depth of its skin pixels while the two hands are apart; when a 2-means split of one skin region
  (:meth:`_split_shared`, :meth:`_reacquire_from_merge`) cannot tell the parts apart in the image (their distances
  from the remembered centre within ``depth_order.IMAGE_SURE``), the track remembered nearer the camera takes the
  nearer part (:mod:`tracker.hands.depth_order`). Tuning seeds 0–4 of ``hands-s2``, ground-truth start, eight filter
  seeds: at the splits where depth decides (1 cm gaps) it was right more often than the image-only rule (19 of 27
  against 15); mean F̄^b 0.694 → 0.691 with 1 cm gaps, 0.699 with 2 cm (seed 2 0.634 → 0.690, seed 4 0.600 →
  0.557: a right split did not keep the hidden hand's track on it); the hands also change their depth order while
  they touch (the order of their last apart frame holds in 82 % of the overlapping ground-truth frames). Held-out
  seeds 100, 101: PF F̄^b 0.683 as without it (it hardly fires there). Off.
* Coasting only behind something nearer (product addition, ``coast_depth`` with ``coast``, off by default): a track
  coasts only while at least ``depth_order.OCCLUDER_SHARE`` of its predicted box lies nearer than its hand's last
  depth by ``depth_order.OCCLUDER_GAP`` (the other hand's arm in front of it). Tuning seeds 0–4 of ``hands-s2``,
  eight filter seeds: 0.691 against 0.694 with neither (``coast`` alone 0.646 on four filter seeds). Off.
* Group box (product addition, ``group_box``, on): while the two tracks' boxes share one colour component whose box
  is at most ``group_box.GROUP_AREA`` (2.4) times a one-hand box, one hand lies on the other and both tracks report
  the component's box; the filters go on unchanged (:mod:`tracker.hands.group_box`). Tuning seeds 0–4 of
  ``hands-s2``, ground-truth start, eight filter seeds (40 runs): F̄^b 0.697 → 0.729, ē^p 22.2 → 21.7 px (filter
  seeds 0–3: 0.681 → 0.714, 23.3 → 22.7 px; 4–7: 0.713 → 0.744, 21.1 → 20.6 px). GROUP_AREA 1.8 / 2.4 / 3.0 with the
  exclusion, filter seeds 0, 1: 0.724 / 0.749 / 0.752 (without the group box 0.708).
* Each hand at the end of its own arm (product addition, ``arm_anchor``, on): while two tracks are live, the hands at
  the far ends of the sleeved arms that enter from the image border are found in every frame without tracking (the
  foreground against the first, hand-free depth frame; the sleeve's far end next to skin as the wrist; the skin split
  between the wrists by a geodesic distance that pays for crossing a depth step, the upper hand's edge, and, when it
  ran on the previous frame too, for taking a pixel the previous split gave the other arm, ``arm_anchor.KEEP_COST``;
  :mod:`tracker.hands.arm_anchor`); each track id remembers where its arm enters the image and reports its arm's
  hand box when that arm is found (after the group box), and with ``arm_reset`` (on) a filter whose box scores below
  ARM_RESET_F against that box restarts on it (a filter on the other hand, or both on one hand, is put back on its
  own). A remembered entry that no arm lies near any more (the arm split into two border pieces as it entered at an
  image corner and the track took the piece that then vanished, or the arm slid round the corner: traced on tuning
  seed 0, the entry 100 working px from the arm for the rest of the session) is re-learnt (ARM_RELEARN): after the
  entry matches, such a track takes an arm no track took whose hand box matches its box as a new track would.
  Tuning seeds 0–4 of ``hands-s2`` (real skin tones), automatic start, filter seeds 0–3 (20 runs): F̄^b 0.868 →
  0.877, ē^p 8.6 → 7.5 px, missed hands 3.2 % → 0.3 %, false boxes 0.053 → 0.003 per frame, 11 runs better, none
  worse; ground-truth start (filter seeds 0, 1) identical. The arms themselves, tuning seeds 0–4 of ``hands-s2``,
  ground-truth start, eight filter seeds (40 runs): reporting only, F̄^b
  0.714 → 0.791, ē^p 22.7 → 13.2 px (filter seeds 0–3), 0.744 → 0.815, 20.6 → 11.7 px (4–7), 39 of 40 runs better,
  none worse; with ``arm_reset`` 0.823 / 11.9 px (0–3) and 0.819 / 11.7 px (4–7), against reporting only 12 runs
  better, 4 worse (seed 4 0.750 → 0.745). Not kept: seeding a hand only with skin at its wrist's depth (0.8033 →
  0.8034, seed 1 −0.016, seed 4 +0.013). Tuning seeds never hold a foreground over 37 % of the frame
  (``arm_anchor.MAX_FG_FRAC`` 0.5). One hand (S1, S3, ground-truth start) unchanged: it runs only with two live
  tracks. Cost (hands-s2 tuning seeds 0–4, filter seed 0, thread CPU per frame against ``arm_anchor`` off in the same
  process, load 8): 2.5 ms with the compiled detector (7.7 ms with the NumPy one of session 17, load 5); it rests
  while the two tracks' boxes are more than ``arm_near_px`` 16 working px apart and its last run agreed with both
  filters (``arm_every`` 5: it runs on 1624 of 1940 two-track frames of seeds 0, 2, 4, 0.7 ms less per frame at load
  5): F̄^b 0.8226 → 0.8246, ē^p 11.93 → 11.75 px (filter seeds 0–3), 0.8188 → 0.8198, 11.67 → 11.59 px (4–7), one of
  40 runs worse by more than 0.005 (−0.007). Resting whenever the boxes do not overlap, checking every 10th frame,
  ran on 1240 of 1644 frames: 0.8247 / 11.77 px (0–3) but 0.8187 / 11.75 px (4–7), three runs worse: not kept.
* Mutual exclusion (product addition, ``exclusion``, off): each particle of a track loses weight by
  exp(−10 · max(0, F − 0.5)), F its box F-score with the other track's predicted box (:mod:`tracker.hands.exclusion`),
  so that the lower hand's track does not follow the top hand onto its box (two real palm boxes score above 0.6 in
  2 % of the frames of tuning seeds 0–4 of ``hands-s2``, the two tracks' estimates did in 10 %). It ends that
  (frames with both tracks on one hand 411 → 12, filter seeds 0, 1) but keeps a swap once the tracks are on each
  other's hands. With the group box, tuning seeds 0–4: filter seeds 0–3 F̄^b 0.714 → 0.744, ē^p 22.7 → 19.8 px,
  filter seeds 4–7 0.744 → 0.719, 20.6 → 23.7 px (one run 0.30: a swap kept for 250 frames); only between tracks
  whose predicted boxes are apart (F < APART_F) 0.738 / 0.719, the same. Not consistent: off. Held-out seeds 100,
  101 with both on (commit f5ef2c4, run before this was decided): PF F̄^b 0.453, ē^p 73.3 px.
* Re-seeding (product addition, particle filter, ``reseed``): a track whose box holds part of a hand-sized colour
  component that no other track touches is offered the component's tight box; the likelihood decides
  (:meth:`HandTracker._reseed`).
* A collapsed track restarts where its hand comes out (product addition, ``collapse_reacquire``, on since session
  20): while two tracks are live, a track whose box holds less than COLLAPSE_FRAC of the colour pixels it held over
  its last COLLAPSE_WINDOW frames (its hand went under the other arm's sleeve, the track sits on a fingertip) restarts,
  with its id, on a moving skin region no other track explains (a candidate as for re-acquisition) instead of
  waiting to end and be re-acquired (:meth:`_update_collapse`). Not with a single track (a lone hand that turns or
  leaves collapses too; a restart there took skin-like regions: false boxes on ``hands-s1`` tuning seed 3 0 → 0.025
  per frame in session 9 and again in session 20). Session 20, tuning seeds 0–4 of ``hands-s2``: ground-truth start,
  filter seeds 0, 1, F̄^b 0.8633 → 0.8718, ē^p 8.58 → 8.03 px (seeds 0, 2, 4 better, 1 and 3 equal); automatic
  start F̄^b 0.8722 → 0.8737, missed hands 1.6 % → 0.07 %, false boxes 0.022 → 0.006 per frame; ``hands-s1`` and
  ``hands-s3`` unchanged.
* Lost tracks (product addition, ``reacquire``): an ended track keeps its id for ``keep_lost`` frames. While one
  waits, a candidate as above also qualifies away from the border if its box centre moved ≥ REACQUIRE_MOVE working
  px over its n_init frames (a moving skin region no track explains: the hand a track lost, or left to the other
  hand); it restarts the lost track whose appearance fits best (else the one last seen nearest) with that id. This
  runs with ``auto_init`` off too (a track started by hand comes back). Two live tracks whose appearance fits the
  other's hand better for SWAP_FRAMES frames exchange ids (they came out of an overlap on each other's hands); a
  live track that fits a lost track's appearance better takes that id. Appearance is learnt only while a track is
  isolated, confident and settled (SETTLE frames after a merge or a restart, no lost track waiting) and only from
  observations that resemble its model (identity.LEARN_MIN_SIM).

Skin model: the shipped generic model (:mod:`tracker.hands.skin_model`); with ``session_background`` its ω2 is
refitted on the session's first frame (assumed hand-free, as thesis Application 2 trains ω2 on the first frames),
and with ``adapt`` the skin means are MAP-adapted every ``adapt_every`` frames to the inner colour-mask pixels of
confident, isolated track boxes (a_{c,1} ≥ 0.5) of the last ``adapt_every`` frames, always from the unadapted session
model and by at most :data:`ADAPT_MAX_SHIFT` (the unbounded, chained adaptation drifted onto sleeve and table colours).

Track ids are 1, 2, 3, … in order of creation; a re-acquired or swapped track carries an earlier id back, a new
hand gets a new id.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import cv2
import numba as nb
import numpy as np

from tracker.hands import arm_anchor, depth_order, edge_refine, exclusion, group_box, identity, order_stats, ownership
from tracker.hands.blob_split import split_shared_components, two_means
from tracker.hands.box_stats import box_area, box_observation, box_of, dominant_component, mask_count
from tracker.hands.features import HandFeatures, compute_features
from tracker.hands.kalman import HandKalmanFilter
from tracker.hands.motion_clusters import MotionClusters
from tracker.hands.palm_cut import cropped_components, match_anchor, palm_anchors, palm_cut
from tracker.hands.particle_filter import HandParticleFilter, PFParams
from tracker.hands.skin_model import SkinModel
from tracker.hands.track_boxes import (
    border_band,
    box_f_score,
    boxes_overlap,
    clipped_box,
    inside_fraction,
    state_box,
    touches_border,
)
from tracker.hands.track_identity import (
    APART_F,
    ESTABLISHED,
    SETTLE,
    TrackIdentity,
)

METHODS = ("pf", "kalman")
REACQUIRE_MOVE = 2.0
"""Working px a candidate away from the border must move over its n_init frames to re-acquire a lost track."""
ADAPT_MAX_SHIFT = 1.0
"""Largest move (Mahalanobis distance in its component's covariance) of a skin mean by the session adaptation."""
MERGED_KEEP = 120
"""Frames two established tracks may share one box (two hands on top of each other) before the worse one ends."""
RESEED_F = 0.7
"""Box F-score with its colour component below which a track is offered the component's box (_reseed)."""
RESEED_SHARE = 0.8
"""Share of a track box's colour pixels that must belong to the component it is offered (_reseed)."""
COAST_DROP = 0.5
"""Share of a track's reference colour-pixel count below which its hand counts as covered (_covered)."""
COAST_MAX = 10
"""Most frames in a row a covered track moves on its velocity alone."""
COAST_HISTORY = 10
"""Frames of (colour pixels in the predicted box, state) a track remembers for _covered."""
COAST_NEAR = 1.0
"""A covered track's predicted box, grown by this many box sizes on every side, must reach another track's box."""
SPLIT_HAND_M = 0.13
"""Longest side (m) above which a colour component shared by two tracks is taken for two hands and split."""
REACQ_GROWTH = 1.5
"""Box area, in units of its one-hand area, from which a lone track's box may hold a lost track's hand as well."""
REACQ_MIN_SHARE = 0.3
"""Share of the component's pixels each part of its 2-means split must hold to give a lost track its hand back."""
RESEED_HAND_M = 0.25
"""Longest side (m) of a colour component that can be one hand (fingers spread) for _reseed."""
SPLIT_SKIN = 0.8
"""Share of the two tracks' one-hand colour-pixel counts (summed) the shared component must hold to be split."""
SPLIT_INSIDE = 0.7
"""Share of the smaller track's box that must lie inside the larger one's for :meth:`HandTracker._split_shared`."""
SPLIT_MIN_PART = 0.6
"""Smallest part box of that split, in units of the smaller one-hand area of the two tracks."""
ONE_HAND_GROWTH = 1.2
"""Box area, in units of its one-hand area, up to which a track's centre counts as its own hand's (centre_one)."""
APART_INSIDE = 0.2
"""A track's box counts as its hand's alone (its area is its one-hand area for :meth:`HandTracker._split_shared`) while
less than this share of it lies in another track's box and of the other's in it."""
COLLAPSE_FRAC = 0.25
"""Share of the most colour pixels its box held over the last COLLAPSE_WINDOW frames below which a track's hand has
gone out of sight (collapsed onto a speck, e.g. the hand went under the other arm)."""
COLLAPSE_WINDOW = 15
"""Frames of colour-pixel counts a track remembers for the collapse test."""
ARM_MATCH_F = 0.5
"""Box F-score with an arm's hand box from which a track without a remembered arm takes that arm (_report_arms)."""
ARM_ENTRY_NEAR = 40.0
"""Working px an arm's entry may lie from a track's remembered entry to be that track's arm (_report_arms)."""
ARM_RELEARN = True
"""A track whose remembered arm entry no arm lies near takes, after the entry matches, an arm no track took whose hand
box matches its box (F-score ≥ ARM_MATCH_F), and remembers that arm's entry (_report_arms)."""
ARM_KEEP_MERGED = True
"""Two established tracks that share one box (duplicates, MERGED_KEEP) are both kept while the arm detector's last run
gave each of them its own arm (_terminate): the two hands lie on top of each other and each is still found."""
ARM_RESET_F = 0.3
"""Box F-score with its arm's hand box below which a filter restarts there (``arm_reset``)."""
ARM_AGREE_F = 0.8
"""Box F-score with its arm's hand box from which a filter agrees with its arm (``arm_near_px``: the detector may then
rest while the two tracks are apart)."""
CLAIM_CERTAIN = 0.5
"""Share of its particles in the section-6 mode from which a track claims the unowned skin pixels of its box in the
owner map (:mod:`tracker.hands.ownership`)."""
EXIT_END = True
"""A track whose box reaches the image border (within the candidates' border band b) and holds no colour pixel of the
frame ends at once (_terminate): its hand has left the image (product addition, session 32)."""


@dataclass(frozen=True)
class HandTrackerConfig:
    """``method`` "pf" | "kalman"; ``scale``: the tracker works on the image downscaled by this integer factor
    (2: 320×240 for a 640×480 stream; pixel constants of the spec are converted, σ's of 1 px stay 1 working px);
    ``n_particles`` N_s (N_T = ⌊N_s/2⌋); ``n_clusters`` N_c; ``flow`` "dis" | "dis-fast" | "farneback";
    ``roi_limit`` L_ROI (full-resolution px); ``max_tracks``; ``auto_init``; ``session_background``; ``adapt`` /
    ``adapt_every``; ``log_tau`` LRT threshold (None: the model's; −2 tuned on simulator seeds 0–4);
    ``ac_hat`` / ``am_hat`` â_{c,1} (thesis 0.9; 0.55 = the mean colour coverage of the ground-truth palm boxes of
    the rendered hands, measured on seeds 0–2: the fingers are spread), â_{m,1} (thesis 0.85; 0.45 tuned on seeds 0
    and 2 of S2, S3: the principal motion cluster covers at most the skin part of the box); ``hand_length_m``: the
    length of the palm box along the arm in L_hand (spec 0.19 m, a whole hand; 0.08 m tuned on seeds 0–2 of S3: the
    ground-truth palm box of a hand grasping from above is foreshortened and starts at the wrist); ``palm_cut``: the
    wrist-cut anchors (:mod:`tracker.hands.palm_cut`, needs depth); ``palm_tube``: an arm's palm is its far end
    within ``palm_reach_m`` without the fitted forearm tube's pixels, except within ``palm_tip_m`` of the end
    (:func:`tracker.hands.palm_cut.tube_cut`; ``hand_length_m`` then only cuts components where no tube fits; tuning
    seeds 0–4 of S3, ground-truth start: F̄^b 0.830 → 0.882, ē^p 11.9 → 7.5 px with reach 0.10 m, 0.875 / 8.4 px
    with 0.12 m, 0.871 / 8.8 px with 0.11 m; S1 bit-identical, S2 0.717 → 0.715 on one filter seed);
    ``reacquire`` / ``keep_lost``: lost tracks and
    identity (see the module docstring); ``reseed``: offer a particle-filter track the box of its hand's own colour
    component (:meth:`HandTracker._reseed`); ``split_blobs`` / ``coast`` / ``merge_reacquire`` / ``shared_split``:
    the blob split, coasting, re-acquisition from a merged component and the split of two touching hands under one
    grown box (module docstring); ``ownership``: each track's own skin pixels while two hands touch
    (:mod:`tracker.hands.ownership`); ``depth_identity``: the depth order decides a 2-means split the image cannot;
    ``coast_depth``: coasting only behind something nearer (module docstring); ``exclusion``: two tracks'
    particles are penalised for taking the other track's box (:mod:`tracker.hands.exclusion`); ``group_box``: two
    stacked hands both report their shared colour component's box (:mod:`tracker.hands.group_box`); ``arm_anchor``:
    each of two tracks reports the hand at the far end of its own arm (:mod:`tracker.hands.arm_anchor`), ``arm_reset``
    also restarts a filter that is far from it there; ``arm_near_px`` / ``arm_every``: the arm detector runs every
    frame only while the two tracks' boxes lie within ``arm_near_px`` working px of each other (0: while they overlap),
    or its last run disagreed with a filter (box F-score below ARM_AGREE_F) or missed an arm, else every
    ``arm_every``-th frame (None: every frame);
    ``isolation_margin``: a track's
    appearance is learnt and compared for id swaps only while its box grown by this many box sizes on every side meets
    no other track's box (default identity.MARGIN, the appearance region; 0 gave F̄^b 0.702 against 0.694 on tuning
    seeds 0–4 of hands-s2, eight filter seeds, and 0.683 as 0.5 on held-out seeds 100, 101); ``edge_refine``: each
    reported box's colour edges placed on the full-resolution colour mask (:mod:`tracker.hands.edge_refine`, on
    since session 30: the working resolution loses the mixed blocks of a shaded rim); ``seed`` of the filters'
    random numbers."""

    method: str = "pf"
    scale: int = 2
    n_particles: int = 30
    n_clusters: int = 4
    flow: str = "dis"
    roi_limit: int = 192
    max_tracks: int = 2
    auto_init: bool = True
    session_background: bool = True
    adapt: bool = True
    adapt_every: int = 15
    log_tau: float | None = -2.0
    seed: int = 0
    min_area_frac: float = 0.0015
    n_init: int = 3
    n_lost: int = 10
    hand_length_m: float = 0.08
    palm_cut: bool = True
    palm_tube: bool = True
    palm_reach_m: float = 0.10
    palm_tip_m: float = 0.05
    reacquire: bool = True
    keep_lost: int = 300
    reseed: bool = True
    split_blobs: bool = False
    coast: bool = False
    coast_depth: bool = False
    merge_reacquire: bool = True
    collapse_reacquire: bool = True
    shared_split: bool = True
    isolation_margin: float = identity.MARGIN
    ownership: bool = False
    depth_identity: bool = False
    exclusion: bool = False
    group_box: bool = True
    arm_anchor: bool = True
    arm_reset: bool = True
    arm_near_px: float | None = 16.0
    arm_every: int = 5
    ac_hat: float = 0.55
    am_hat: float = 0.45
    edge_refine: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"hand tracker method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.n_particles < 1:
            raise ValueError(f"the particle count must be at least 1, got {self.n_particles}")
        if not 1 <= self.n_clusters <= 8:
            raise ValueError(f"the motion cluster count must be within 1–8, got {self.n_clusters}")


@dataclass
class HandEstimate:
    """One hand at one frame: track ``id``, ``state`` (x, y, w, h, x', y') in px and px/frame, ``box`` [u0, v0,
    u1, v1] (end-exclusive, clipped to the image), ``score`` = a_{c,1} (colour coverage of the box, 0..1),
    ``n_eff`` N_eff/N_s and ``certain`` (fraction of particles in the section-6 mode)."""

    id: int
    state: np.ndarray
    box: list[int]
    score: float
    n_eff: float
    certain: float

    def to_dict(self) -> dict:
        return {"id": self.id, "box": list(self.box), "score": round(float(self.score), 4)}


@dataclass
class _Track:
    id: int
    filt: HandParticleFilter | HandKalmanFilter
    age: int = 0
    low: int = 0
    tiny: int = 0
    dup: dict[int, int] = field(default_factory=dict)
    score: float = 1.0
    app: np.ndarray | None = None
    swap: dict[int, int] = field(default_factory=dict)
    merged: bool = False
    apart: int = 0
    since_merge: int = 1 << 30
    coasting: int = 0
    hist: deque = field(default_factory=lambda: deque(maxlen=COAST_HISTORY))
    area_ref: float = 0.0
    area_apart: float = 0.0
    skin_now: int = 0
    skin_apart: float = 0.0
    since_split: int = 1 << 30
    centre_one: np.ndarray | None = None
    centre_ref: np.ndarray | None = None
    skin_hist: deque = field(default_factory=lambda: deque(maxlen=COLLAPSE_WINDOW))
    collapsed: bool = False
    hold_id: int = 0
    key: int = 0
    z_apart: float = float("nan")
    z_frame: int = -(1 << 30)


@dataclass
class _Lost:
    """A track that ended (left the image, lost its hand, or duplicated another track) and keeps its id for
    re-acquisition: ``state`` its last estimate (working px), ``frames`` since it ended."""

    id: int
    state: np.ndarray
    frames: int = 0
    app: np.ndarray | None = None
    z_apart: float = float("nan")
    z_frame: int = -(1 << 30)


@dataclass
class _Candidate:
    box: tuple[int, int, int, int]
    seen: int
    border: bool = True
    first: tuple[float, float] = (0.0, 0.0)


class HandTracker(TrackIdentity):
    """Hand tracks over a colour stream; :meth:`process` one RGB frame at a time (uint8 H×W×3).

    Internally everything runs on the frame downscaled by ``config.scale`` (working pixels); estimates are returned
    in full-resolution pixels (a working pixel i covers full pixels s·i … s·i + s − 1)."""

    def __init__(self, config: HandTrackerConfig | None = None, skin_model: SkinModel | None = None,
                 focal: float | None = None) -> None:  # fmt: skip
        self.config = config or HandTrackerConfig()
        cfg = self.config
        model = skin_model or SkinModel.load()
        if cfg.log_tau is not None:
            model = model.with_threshold(cfg.log_tau)
        self.skin = model
        self.focal = focal
        self.s = max(1, int(cfg.scale))
        s2 = float(self.s * self.s)
        self.pf_params = PFParams(n_particles=cfg.n_particles, n_min=max(1, int(round(10 / s2))), ac_hat=cfg.ac_hat,
                                  am_hat=cfg.am_hat, d2_scale=80.0 / s2, v2_scale=7.0 / s2)  # fmt: skip
        self.rng = np.random.default_rng(cfg.seed)
        self.clusters = MotionClusters(cfg.n_clusters, seed=cfg.seed)
        self._flows: dict = {}  # this tracker's own optical-flow instances (tracker.hands.flow.flow)
        self.tracks: list[_Track] = []
        self.lost: list[_Lost] = []
        self.next_id = 1
        self.frame_index = -1
        self.full_size: tuple[int, int] | None = None
        self._prev_rgb: np.ndarray | None = None
        self._prev_grey: np.ndarray | None = None
        self._excl: np.ndarray | None = None  # this frame's working-resolution "cannot be a hand" mask (or None)
        self._prev_excl: np.ndarray | None = None
        self._depth: np.ndarray | None = None
        self._bins: np.ndarray | None = None  # this frame's appearance bin image (tracker.hands.identity)
        self._bg_bins: np.ndarray | None = None
        self._cur_rgb: np.ndarray | None = None
        self._mask_cur: np.ndarray | None = None  # this frame's colour mask B^c over the whole working frame
        self._mask_prev: np.ndarray | None = None
        self._candidates: list[_Candidate] = []
        self._adapt_pixels: deque[np.ndarray] = deque(maxlen=2 * self.config.max_tracks * self.config.adapt_every)
        self._skin_base = model  # the session's unadapted model (adaptation starts from it every time)
        self.last_features: HandFeatures | None = None
        self._key = 0  # last track key given (tracker.hands.ownership: keys stay with a track object, ids may swap)
        self._owner: np.ndarray | None = None  # owner map of the last processed frame (tracker.hands.ownership)
        self._own_step: tuple | None = None  # (roi, mcur, propagated owners) of this frame's step
        self._fresh: list[int] = []  # keys of the tracks started since the owner map was last settled
        self._arm_bg: np.ndarray | None = None  # the first frame's depth at the working resolution (arm_anchor)
        self._entries: dict[int, tuple[float, float]] = {}  # track id -> where its arm enters the image (arm_anchor)
        self._arm_idle = 0  # frames since the arm detector last ran (arm_every)
        self._arm_agreed = False  # whether its last run found both tracks' arms and restarted no filter
        self._arm_own: set[int] = set()  # ids of the tracks its last run gave an arm of their own
        self._arm_split: tuple[int, arm_anchor.ArmSplit] | None = None  # its last run's frame index and split

    # ------------------------------------------------------------------ resolution
    def to_full(self, state: np.ndarray) -> np.ndarray:
        """A working-resolution state in full-resolution pixels."""
        s = self.s
        out = np.asarray(state, float).copy()
        out[:2] = s * out[:2] + (s - 1) / 2.0
        out[2:4] = s * out[2:4] + (s - 1)
        out[4:] = s * out[4:]
        return out

    def from_full_box(self, box_excl) -> np.ndarray:
        """Working-resolution state (velocity 0) of a full-resolution end-exclusive box."""
        s = self.s
        u0, v0, u1, v1 = (int(b) for b in box_excl)
        a0, b0, a1, b1 = u0 // s, v0 // s, (u1 - 1) // s, (v1 - 1) // s
        return np.array([(a0 + a1) / 2.0, (b0 + b1) / 2.0, a1 - a0, b1 - b0, 0.0, 0.0])

    def _skin(self, rgb: np.ndarray, excl: np.ndarray | None, y0: int = 0, y1: int | None = None, x0: int = 0,
              x1: int | None = None) -> np.ndarray:  # fmt: skip
        """Colour mask B^c (uint8 0/1) of the working-resolution crop ``rgb[y0:y1, x0:x1]``, with the pixels of the
        exclusion mask ``excl`` (working resolution, whole frame; None: none) set to 0."""
        m = self.skin.mask(rgb[y0:y1, x0:x1])
        if excl is not None:
            m[excl[y0:y1, x0:x1]] = 0
        return m

    # ------------------------------------------------------------------ tracks
    def start_track(self, box_excl: list[int] | tuple[int, ...]) -> int:
        """Start a track on a full-resolution end-exclusive box [u0, v0, u1, v1] of the last processed frame (manual
        or ground-truth start); returns its id."""
        if self._prev_rgb is None:
            raise RuntimeError("hand tracker: process a frame before starting a track on it")
        tid = self._start(self.from_full_box(box_excl))
        if self.config.ownership and self._owner is not None and self._mask_prev is not None:
            self._claim(self._owner, self._mask_prev)
        return tid

    def _start(self, x1: np.ndarray, tid: int | None = None) -> int:
        cfg = self.config
        if cfg.method == "pf":
            filt: HandParticleFilter | HandKalmanFilter = HandParticleFilter(
                x1, self.pf_params, cfg.n_clusters, np.random.default_rng(self.rng.integers(1 << 62)))
        else:
            filt = HandKalmanFilter(x1, cfg.n_clusters, sigma_q=2.0 / self.s)
        if tid is None:
            tid = self.next_id
            self.next_id += 1
        self._key += 1
        self.tracks.append(_Track(tid, filt, key=self._key))
        self._fresh.append(self._key)
        return tid

    def hand_masks(self) -> dict[int, np.ndarray]:
        """Skin mask M_k = B(x_k) ∩ B^c_k (spec §14.4) of every live track at the last processed frame, as a
        full-resolution bool H×W image per track id (working pixels repeated ``scale`` times)."""
        return {tid: self._upsampled(m) for tid, m in self.hand_masks_small().items()}

    def hand_masks_small(self) -> dict[int, np.ndarray]:
        """:meth:`hand_masks` at the working resolution (uint8 0/1 images of the working frame's size)."""
        out: dict[int, np.ndarray] = {}
        if self._prev_rgb is None or self.full_size is None:
            return out
        h, w = self._prev_rgb.shape[:2]
        for tr in self.tracks:
            u0, v0, u1, v1 = state_box(tr.filt.estimate)
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w - 1), min(v1, h - 1)
            m = np.zeros((h, w), np.uint8)
            if u1 >= u0 and v1 >= v0:
                if self._mask_prev is not None:
                    m[v0 : v1 + 1, u0 : u1 + 1] = self._mask_prev[v0 : v1 + 1, u0 : u1 + 1]
                else:
                    m[v0 : v1 + 1, u0 : u1 + 1] = self._skin(self._prev_rgb, self._prev_excl, v0, v1 + 1, u0, u1 + 1)
            out[tr.id] = m
        return out

    def arm_mask(self) -> np.ndarray | None:
        """The colour components of the last processed frame that reach into a live track's box (the hand with a
        bare forearm, spec §14.5): the 4-connected components of B^c_k (opened with a 3×3 cross, so that scattered
        false skin pixels do not join) that hold a pixel of some track's box, as a full-resolution bool H×W image; None
        without tracks."""
        small = self.arm_mask_small()
        return None if small is None else self._upsampled(small)

    def arm_mask_small(self) -> np.ndarray | None:
        """:meth:`arm_mask` at the working resolution (uint8 0/1), None without tracks or components."""
        if self._prev_rgb is None or self.full_size is None or not self.tracks:
            return None
        m = self._mask_prev if self._mask_prev is not None else self._skin(self._prev_rgb, self._prev_excl)
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)))
        _, lab = cv2.connectedComponents(m, connectivity=4, ltype=cv2.CV_32S)
        h, w = lab.shape
        keep: set[int] = set()
        for tr in self.tracks:
            u0, v0, u1, v1 = state_box(tr.filt.estimate)
            sub = lab[max(v0, 0) : max(min(v1 + 1, h), 0), max(u0, 0) : max(min(u1 + 1, w), 0)]
            keep.update(int(v) for v in np.unique(sub) if v)
        if not keep:
            return None
        chosen = np.zeros(int(lab.max()) + 1, np.uint8)
        chosen[np.fromiter(keep, np.int64)] = 1
        return chosen[lab]

    def _upsampled(self, small: np.ndarray) -> np.ndarray:
        """A working-resolution 0/1 image as a full-resolution bool H×W image (each working pixel repeated ``scale``
        times along both axes; rows and columns past the working image stay False)."""
        assert self.full_size is not None
        W, H = self.full_size
        s = self.s
        out = np.zeros((H, W), bool)
        x, y, w, h = cv2.boundingRect(np.ascontiguousarray(small.view(np.uint8)))  # only the set pixels' rectangle
        if w == 0 or h == 0:
            return out
        crop = small[y : y + h, x : x + w].view(bool)
        up = crop if s == 1 else np.broadcast_to(crop[:, None, :, None], (h, s, w, s)).reshape(h * s, w * s)
        hh, ww = min(H - y * s, h * s), min(W - x * s, w * s)
        if hh > 0 and ww > 0:
            out[y * s : y * s + hh, x * s : x * s + ww] = up[:hh, :ww]
        return out

    # ------------------------------------------------------------------ frames
    def process(self, rgb: np.ndarray, depth: np.ndarray | None = None,
                exclude: np.ndarray | None = None) -> list[HandEstimate]:  # fmt: skip
        """Track the hands in the next frame (RGB uint8 H×W×3, optional registered depth in metres); returns one
        estimate per live track after this frame's update, in full-resolution pixels.

        ``exclude``: pixels that cannot be a hand whatever their colour (bool; at full resolution H×W or at the
        working resolution H/scale × W/scale), e.g. the table plane and the parts' own surfaces
        (:mod:`tracker.hands.loop`); they are left out of the colour mask B^c."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"hand tracker: expected an H×W×3 uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        H, W = rgb.shape[:2]
        if self.full_size is not None and self.full_size != (W, H):
            raise ValueError(f"hand tracker: frame size changed from {self.full_size} to {(W, H)}")
        self.full_size = (W, H)
        s = self.s
        small = rgb if s == 1 else cv2.resize(rgb, (W // s, H // s), interpolation=cv2.INTER_AREA)
        small = np.ascontiguousarray(small)
        grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
        size = (small.shape[1], small.shape[0])
        self._excl = self._working_mask(exclude, H, W, size)
        self._depth = depth
        self.frame_index += 1
        out: list[HandEstimate] = []
        self._bins = None
        self._cur_rgb = small
        if self._prev_rgb is None:
            self._bg_bins = identity.background_bins(self._bin_image(small))
            if self.config.session_background:
                self.skin = self.skin.with_background(small, step=2, keep=None if self._excl is None else ~self._excl)
            self._skin_base = self.skin
            if self.config.arm_anchor and depth is not None:
                self._arm_bg = arm_anchor.working_depth(depth, s, small.shape[:2])
        self._mask_cur = None
        if self._prev_rgb is not None and self.tracks:
            out = self._step_tracks(small, grey, size)
        for lo in self.lost:
            lo.frames += 1
        self.lost = [lo for lo in self.lost if lo.frames <= self.config.keep_lost]
        new_ok = self.config.auto_init and len(self.tracks) + len(self.lost) < self.config.max_tracks
        pair = self._shared_pair() if self.config.reacquire and len(self.tracks) > 1 else None
        collapsed = ([tr for tr in self.tracks if tr.collapsed]
                     if self.config.collapse_reacquire and len(self.tracks) > 1 else [])  # fmt: skip
        if new_ok or self.lost or pair is not None or collapsed:
            new = self._auto_init(small, depth, reacquire=bool(self.lost) or pair is not None or bool(collapsed),
                                  ignore=collapsed)  # fmt: skip
            if new is not None:
                if collapsed and not self.lost:  # a collapsed track's hand came back out of sight: it restarts there
                    moved = self._restart_collapsed(collapsed, new, small)
                    out = [e for e in out if e.id != moved]
                elif self.lost:  # a lost track comes back with its id (see _pick_lost)
                    lo = self.lost.pop(self._pick_lost(new, small))
                    self._start(new, lo.id)
                    self.tracks[-1].app = lo.app
                    self.tracks[-1].since_merge = 0
                elif pair is not None and not new_ok:  # a free hand while two tracks share one region: one moves to it
                    moved = self._transfer(pair, new, small)
                    out = [e for e in out if e.id != moved]
                else:
                    self._start(new)
                out.append(self._estimate(self.tracks[-1], size))
            elif pair is not None and self.config.shared_split and not self.lost:
                moved = self._split_shared(pair, small)
                if moved is not None:
                    out = [e for e in out if e.id not in moved]
                    out += [self._estimate(tr, size) for tr in self.tracks if tr.id in moved]
            elif self.lost and len(self.tracks) == 1 and self.config.merge_reacquire:
                back = self._reacquire_from_merge(small)
                if back is not None:
                    out = [e for e in out if e.id != self.tracks[0].id]
                    out += [self._estimate(tr, size) for tr in self.tracks]
        if self.config.ownership:
            self._settle_owner(small.shape[:2])
            self._fresh = []  # a track started here (automatic start, re-acquisition) claims pixels once it is certain
        self._prev_rgb = small
        self._prev_grey = grey
        self._prev_excl = self._excl
        self._mask_prev = self._mask_cur
        if self.config.edge_refine and s > 1 and out:
            self._refine_edges(out, rgb, exclude)
        return out

    def _refine_edges(self, ests: list[HandEstimate], rgb: np.ndarray, exclude: np.ndarray | None) -> None:
        """Each estimate's colour edges placed on the full-resolution colour mask (``edge_refine``,
        :mod:`tracker.hands.edge_refine`); the state's centre and size follow the box. ``exclude`` counts only at full
        resolution."""
        H, W = rgb.shape[:2]
        ex = exclude if exclude is not None and np.shape(exclude) == (H, W) else None

        def mask_of(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
            m = self.skin.mask(rgb[y0:y1, x0:x1])
            if ex is not None:
                m[np.asarray(ex[y0:y1, x0:x1], bool)] = 0
            return m

        for e in ests:
            box = edge_refine.refine_box(e.box, mask_of, (W, H), self.s * edge_refine.GROW_WORKING)
            if box != list(e.box):
                st = np.asarray(e.state, float).copy()
                st[:4] = [(box[0] + box[2] - 1) / 2.0, (box[1] + box[3] - 1) / 2.0, box[2] - box[0] - 1,
                          box[3] - box[1] - 1]  # fmt: skip
                e.state = st
                e.box = box

    def _claim(self, owner: np.ndarray, mask: np.ndarray) -> None:
        """Tracks started since the last claim take every skin pixel (``mask``, the working frame's B^c) of their
        box in the owner map (a start box is where the hand is; the other track may have owned those pixels)."""
        fresh, self._fresh = self._fresh, []
        h, w = owner.shape
        for tr in self.tracks:
            if tr.key in fresh:
                u0, v0, u1, v1 = state_box(tr.filt.estimate)
                u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w - 1), min(v1, h - 1)
                if u1 >= u0 and v1 >= v0:
                    sub = owner[v0 : v1 + 1, u0 : u1 + 1]
                    sub[mask[v0 : v1 + 1, u0 : u1 + 1] > 0] = tr.key

    def _settle_owner(self, shape: tuple[int, int]) -> None:
        """The owner map of this frame (:func:`tracker.hands.ownership.settle`) from this frame's step, or None."""
        step, self._own_step = self._own_step, None
        if step is None or not self.tracks:
            self._owner = None
            return
        roi, mcur, own = step
        claim = [tr.filt.det_fraction >= CLAIM_CERTAIN for tr in self.tracks]
        self._owner = ownership.settle(shape, roi, mcur, own, [tr.key for tr in self.tracks],
                                       [tr.filt.estimate for tr in self.tracks], claim)  # fmt: skip

    def _frame_mask(self, rgb: np.ndarray) -> np.ndarray:
        """The colour mask B^c (uint8 0/1) of the whole working-resolution frame ``rgb``, computed once per frame."""
        if self._mask_cur is None:
            self._mask_cur = self._skin(rgb, self._excl)
        return self._mask_cur

    def _working_mask(self, exclude: np.ndarray | None, H: int, W: int, size: tuple[int, int]) -> np.ndarray | None:
        """``exclude`` as a working-resolution bool mask (a full-resolution mask is subsampled every scale-th px)."""
        if exclude is None:
            return None
        ex = np.asarray(exclude, bool)
        if ex.shape == (H, W):
            ex = ex[:: self.s, :: self.s][: size[1], : size[0]]
        if ex.shape != (size[1], size[0]):
            raise ValueError(f"hand tracker: exclusion mask is {ex.shape}, expected {(H, W)} or {(size[1], size[0])}")
        return ex

    def _roi(self, size: tuple[int, int]) -> tuple[int, int, int, int]:
        W, H = size
        x0, y0, x1, y1 = W, H, 0, 0
        for tr in self.tracks:
            e = tr.filt.estimate
            margin = max(24.0 / self.s, 0.5 * max(e[2], e[3]), 2.0 * float(np.hypot(e[4], e[5])))
            boxes = np.ascontiguousarray(np.atleast_2d(tr.filt.boxes_for_roi()), np.float64)
            x0, y0, x1, y1 = _roi_bounds(boxes, float(margin), x0, y0, x1, y1)
        return max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)

    def _step_tracks(self, rgb: np.ndarray, grey: np.ndarray, size: tuple[int, int]) -> list[HandEstimate]:
        cfg = self.config
        roi = self._roi(size)
        x0, y0, x1, y1 = roi
        if x1 - x0 < 8 or y1 - y0 < 8:
            self._end([True] * len(self.tracks))
            self.tracks = []
            return []
        assert self._prev_rgb is not None and self._prev_grey is not None
        if self._mask_prev is not None:
            mprev = np.ascontiguousarray(self._mask_prev[y0:y1, x0:x1])
        else:
            mprev = self._skin(self._prev_rgb, self._prev_excl, y0, y1, x0, x1)
        mcur = np.ascontiguousarray(self._frame_mask(rgb)[y0:y1, x0:x1])
        feats = compute_features(self._prev_grey, grey, mprev, mcur, roi, size, self.clusters, cfg.flow,
                                 max(8, cfg.roi_limit // self.s), backward=cfg.method == "pf",
                                 flow_cache=self._flows)  # fmt: skip
        if cfg.palm_cut:
            feats.anchors = palm_anchors(self._frame_mask(rgb), self._depth, self.s, self._focal_px(),
                                         cfg.hand_length_m, cfg.min_area_frac * size[0] * size[1],
                                         self._tube())  # fmt: skip
        if cfg.split_blobs:
            self._split_blobs(feats)
        self.last_features = feats
        own_feats = self._ownership_features(feats, size) if cfg.ownership else {}
        before = [(_snapshot(tr.filt), state_box(tr.filt.estimate)) for tr in self.tracks]
        avoid = self._exclusion_boxes() if cfg.exclusion and cfg.method == "pf" else None
        for i, tr in enumerate(self.tracks):
            if cfg.coast and self._covered(tr, feats, size):
                tr.filt.coast()
                tr.coasting += 1
            elif avoid is not None and len(self.tracks) > 1:
                assert isinstance(tr.filt, HandParticleFilter)
                tr.filt.step(own_feats.get(tr.key, feats), size, np.delete(avoid, i, axis=0))
                tr.coasting = 0
            else:
                tr.filt.step(own_feats.get(tr.key, feats), size)
                tr.coasting = 0
            tr.age += 1
        self._undo_jumps(before)
        if cfg.method == "pf" and cfg.reseed:
            self._reseed(feats, size)
        ests = [self._estimate(tr, size, own_feats.get(tr.key, feats)) for tr in self.tracks]
        self._update_collapse(feats, size)
        self._update_size_refs()
        keep = self._terminate(size)
        self._end([not k for k in keep])
        self.tracks = [tr for tr, k in zip(self.tracks, keep, strict=True) if k]
        ests = [e for e, k in zip(ests, keep, strict=True) if k]
        if cfg.reacquire:
            self._identity(rgb)
            for e, tr in zip(ests, self.tracks, strict=True):
                e.id = tr.id
        if cfg.group_box:
            self._report_group(ests, feats, size)
        if cfg.arm_anchor and self._arm_bg is not None and self._depth is not None and self._arms_due():
            self._report_arms(ests, rgb, grey)
        if cfg.adapt:
            self._collect_adapt_pixels(rgb, mcur, roi)
            if self.frame_index % cfg.adapt_every == 0 and self._adapt_pixels:
                self.skin = self._skin_base.adapted(np.concatenate(list(self._adapt_pixels)), max_shift=ADAPT_MAX_SHIFT)
                self._mask_cur = None  # the frame's mask under the adapted model, if it is needed again
        return ests

    def _report_group(self, ests: list[HandEstimate], feats: HandFeatures, size: tuple[int, int]) -> None:
        """Two stacked hands (``group_box``, :mod:`tracker.hands.group_box`): both estimates report the box of their
        shared colour component (state centre and size, box), the filters are left as they are."""
        if len(self.tracks) != 2:
            return
        cb = group_box.group_component([tr.filt.estimate for tr in self.tracks],
                                       [tr.area_apart for tr in self.tracks], feats.cc, feats.n_comp, feats.cc_box,
                                       feats.cc_cut, (feats.roi[0], feats.roi[1]))  # fmt: skip
        if cb is None:
            return
        assert self.full_size is not None
        for e in ests:
            st = e.state.copy()
            st[:4] = self.to_full(np.array([(cb[0] + cb[2]) / 2.0, (cb[1] + cb[3]) / 2.0, cb[2] - cb[0], cb[3] - cb[1],
                                            0.0, 0.0]))[:4]  # fmt: skip
            e.state = st
            e.box = clipped_box(st, self.full_size)

    def _arms_due(self) -> bool:
        """Whether the arm detector runs this frame (``arm_near_px``, ``arm_every``): with two live tracks, every
        frame while their boxes lie within ``arm_near_px`` working px of each other (or overlap), while the last run
        disagreed with a filter (restarted it) or did not find both tracks' arms, and every ``arm_every``-th frame
        otherwise."""
        if len(self.tracks) != 2:
            return False
        cfg = self.config
        self._arm_idle += 1
        if cfg.arm_near_px is None or self._arm_idle >= cfg.arm_every or not self._arm_agreed:
            return True
        a, b = (state_box(tr.filt.estimate) for tr in self.tracks)
        gap = max(a[0] - b[2], b[0] - a[2], a[1] - b[3], b[1] - a[3])
        return gap <= cfg.arm_near_px

    def _report_arms(self, ests: list[HandEstimate], rgb: np.ndarray, grey: np.ndarray | None = None) -> None:
        """Each hand at the far end of its own arm (``arm_anchor``, :mod:`tracker.hands.arm_anchor`). Every track id
        remembers where its arm enters the image: first the entry of the arm whose hand box matches the track's box
        (F-score ≥ ARM_MATCH_F), then the nearest entry within ARM_ENTRY_NEAR working px of the remembered one (the
        entry follows the arm); only while two tracks are live. Each reports its arm's hand box; with ``arm_reset`` a
        filter whose box scores below ARM_RESET_F against it restarts there (velocity 0). ``grey``: the working
        frame's grey levels (for ``arm_anchor.EDGE_SPLIT``)."""
        if len(self.tracks) != 2:
            return
        assert self._depth is not None and self._arm_bg is not None and self.full_size is not None
        self._arm_idle = 0
        self._arm_agreed = False
        self._arm_own = set()
        z = arm_anchor.working_depth(self._depth, self.s, rgb.shape[:2])
        last = self._arm_split
        prev = last[1] if last is not None and last[0] == self.frame_index - 1 else None
        ft = self.last_features  # this frame's: its ROI's backward flow for arm_anchor.MOTION_SPLIT
        flow = (ft.fb[0], ft.roi[0], ft.roi[1]) if ft is not None else None
        hands, split = arm_anchor.arm_split(self._frame_mask(rgb), z, self._arm_bg, prev, flow, grey)
        self._arm_split = (self.frame_index, split) if split is not None else None
        if not hands:
            return
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        pairs = []
        for i, tr in enumerate(self.tracks):
            for j, hd in enumerate(hands):
                e = self._entries.get(tr.id)
                if e is None:
                    f = box_f_score(hd.box, boxes[i])
                    if f >= ARM_MATCH_F:
                        pairs.append((1.0 - f, i, j))
                else:
                    dd = float(np.hypot(hd.entry[0] - e[0], hd.entry[1] - e[1]))
                    if dd <= ARM_ENTRY_NEAR:
                        pairs.append((dd, i, j))
                    elif ARM_RELEARN:
                        f = box_f_score(hd.box, boxes[i])
                        if f >= ARM_MATCH_F:  # after every entry match (key above ARM_ENTRY_NEAR): a stale entry
                            pairs.append((2.0 * ARM_ENTRY_NEAR + 1.0 - f, i, j))
        used_t: set[int] = set()
        used_h: set[int] = set()
        agreed = True
        for _, i, j in sorted(pairs):
            if i in used_t or j in used_h:
                continue
            used_t.add(i)
            used_h.add(j)
            tr, hd = self.tracks[i], hands[j]
            self._entries[tr.id] = hd.entry
            b = hd.box
            st = np.array([(b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0, b[2] - b[0], b[3] - b[1], 0.0, 0.0])
            f = box_f_score(b, boxes[i])
            agreed = agreed and f >= ARM_AGREE_F
            if self.config.arm_reset and f < ARM_RESET_F:
                tr.filt.set_state(st)
            for e in ests:
                if e.id == tr.id:
                    full = e.state.copy()
                    full[:4] = self.to_full(st)[:4]
                    e.state = full
                    e.box = clipped_box(full, self.full_size)
        self._arm_agreed = agreed and len(used_t) == 2
        self._arm_own = {self.tracks[i].id for i in used_t} if len(used_t) == 2 else set()

    def _exclusion_boxes(self) -> np.ndarray:
        """Predicted inclusive boxes [n_tracks, 4] (working px) of the live tracks for the mutual exclusion
        (``exclusion``, :mod:`tracker.hands.exclusion`): each estimate moved by its velocity."""
        return np.array([exclusion.predicted_box(tr.filt.estimate) for tr in self.tracks], np.float64).reshape(-1, 4)

    def _ownership_features(self, feats: HandFeatures, size: tuple[int, int]) -> dict[int, HandFeatures]:
        """Per-track features without the other hand's skin pixels while two hands touch (``ownership``,
        :mod:`tracker.hands.ownership`), keyed by track key; empty when no colour component holds two owners."""
        own = None
        if len(self.tracks) > 1 or self.lost:
            keys = [tr.key for tr in self.tracks]
            own = ownership.propagate(feats, self._owner, keys, [tr.filt.estimate for tr in self.tracks])
        self._own_step = (feats.roi, feats.mcur, own)
        if own is None or not ownership.shared(own, feats.cc):
            return {}
        return {tr.key: ownership.track_features(feats, own, tr.key, size) for tr in self.tracks}

    def _split_blobs(self, feats: HandFeatures) -> None:
        """Split a colour component shared by two tracks that each followed a hand of their own (ESTABLISHED frames
        apart) and too large for one hand (longest side above SPLIT_HAND_M at its depth) between them
        (:mod:`tracker.hands.blob_split`)."""
        n = len(self.tracks)
        pairs = [(i, j) for i in range(n) for j in range(i + 1, n)
                 if self.tracks[i].apart >= ESTABLISHED and self.tracks[j].apart >= ESTABLISHED]  # fmt: skip
        if pairs:
            scale = self._focal_px() / self.s

            def two_hands(lab: int) -> bool:
                b = feats.cc_box[lab]
                return max(b[2] - b[0], b[3] - b[1]) > scale * SPLIT_HAND_M / self._component_depth(feats, lab)

            split_shared_components(feats, [tr.filt.estimate for tr in self.tracks], pairs, two_hands)

    def _update_collapse(self, feats: HandFeatures, size: tuple[int, int]) -> None:
        """Product addition (``collapse_reacquire``): flag the tracks whose hand has gone out of sight. A track is
        collapsed when the colour pixels in its estimate's box fall below COLLAPSE_FRAC of the most its box held over
        its last COLLAPSE_WINDOW frames (at least A_min of them; the counts of collapsed frames are not remembered, so
        the reference stays the hand's). Such a track has shrunk onto a speck (a fingertip, the rim of the arm that
        hides the hand) and no longer follows its hand; when a moving skin region that no other track explains turns
        up, the track restarts there (:meth:`_restart_collapsed`) instead of waiting to end and be re-acquired."""
        ox, oy = feats.roi[0], feats.roi[1]
        min_area = self.config.min_area_frac * size[0] * size[1]
        for tr in self.tracks:
            e = tr.filt.estimate
            u0, v0, u1, v1 = box_of(e[0] - ox, e[1] - oy, e[2], e[3])
            n, _ = mask_count(u0, v0, u1, v1, feats.mcur)
            ref = max(tr.skin_hist) if tr.skin_hist else 0
            tr.collapsed = len(tr.skin_hist) >= 3 and ref >= min_area and n < COLLAPSE_FRAC * ref
            tr.skin_now = n
            tr.since_split += 1
            if not tr.collapsed:
                tr.skin_hist.append(n)

    def _restart_collapsed(self, collapsed: list[_Track], state: np.ndarray, rgb: np.ndarray) -> int:
        """The collapsed track (the one whose box lies nearest, if several) restarts on ``state`` with its id and
        appearance; returns that id."""
        tr = min(collapsed, key=lambda t: float(np.hypot(*(t.filt.estimate[:2] - state[:2]))))
        self.tracks.remove(tr)
        self._start(state, tr.id)
        new = self.tracks[-1]
        new.app, new.since_merge, new.apart = tr.app, 0, tr.apart
        new.area_ref, new.centre_ref = tr.area_ref, state[:2].copy()
        new.hold_id = SETTLE  # the hand comes out beside what hid it (the other hand's sleeve): no id swap yet
        return tr.id

    def _update_size_refs(self) -> None:
        """One-hand size and place of each track (for :meth:`_reacquire_from_merge`): with two tracks whose boxes do
        not meet, each track's box area (running mean) and centre; with one track, its centre while its box is not
        grown beyond REACQ_GROWTH of that area."""
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        for i, tr in enumerate(self.tracks):
            b = boxes[i]
            area = float(box_area(b))
            alone = len(self.tracks) == 2 and not any(boxes_overlap(b, o) for j, o in enumerate(boxes) if j != i)
            if alone:
                tr.area_ref = area if tr.area_ref <= 0 else 0.9 * tr.area_ref + 0.1 * area
            if alone or (len(self.tracks) == 1 and 0 < area <= REACQ_GROWTH * tr.area_ref):
                tr.centre_ref = np.asarray(tr.filt.estimate[:2], float).copy()
            others = [o for j, o in enumerate(boxes) if j != i]
            if others and all(max(inside_fraction(b, o), inside_fraction(o, b)) < APART_INSIDE for o in others):
                tr.area_apart = area if tr.area_apart <= 0 else 0.9 * tr.area_apart + 0.1 * area
                n = float(tr.skin_now)
                tr.skin_apart = n if tr.skin_apart <= 0 else 0.9 * tr.skin_apart + 0.1 * n
                if self.config.depth_identity and self._depth is not None and self._mask_cur is not None:
                    z = depth_order.box_skin_depth(self._depth, self._mask_cur, b, self.s)
                    if np.isfinite(z):
                        tr.z_apart, tr.z_frame = z, self.frame_index
            if 0 < area <= ONE_HAND_GROWTH * tr.area_apart:
                tr.centre_one = np.asarray(tr.filt.estimate[:2], float).copy()

    def _reacquire_from_merge(self, rgb: np.ndarray) -> int | None:
        """Product addition (``merge_reacquire``): a lost track's hand that went into the one live
        track's colour component (the two hands on top of each other; no free candidate turns up while they touch)
        comes back by splitting that component. If the live track's box has grown to at least REACQ_GROWTH times its
        one-hand area, the component under it is split in two by 2-means on its pixel positions; if both parts hold
        at least REACQ_MIN_SHARE of its pixels, the live track goes on with the part nearer its last one-hand centre
        and the lost track (chosen as in re-acquisition) restarts on the other part's tight box with its id. Returns
        the re-acquired id, or None."""
        tr = self.tracks[0]
        if tr.area_ref <= 0 or tr.centre_ref is None:
            return None
        b = state_box(tr.filt.estimate)
        if box_area(b) < REACQ_GROWTH * tr.area_ref:
            return None
        pts = self._largest_component(rgb, b)
        if pts is None:
            return None
        parts = two_means(pts)
        if parts is None or min(len(p) for p in parts) < REACQ_MIN_SHARE * len(pts):
            return None
        states = [np.array([(p[:, 0].min() + p[:, 0].max()) / 2.0, (p[:, 1].min() + p[:, 1].max()) / 2.0,
                            np.ptp(p[:, 0]), np.ptp(p[:, 1]), 0.0, 0.0]) for p in parts]  # fmt: skip
        d = [float(np.hypot(*(st[:2] - tr.centre_ref))) for st in states]
        mine, other = (0, 1) if d[0] <= d[1] else (1, 0)
        if self.config.depth_identity and len(self.lost) == 1:
            lo = self.lost[0]
            by_depth = self._depth_assignment((tr.z_apart, tr.z_frame), (lo.z_apart, lo.z_frame), parts, d)
            if by_depth is not None:
                mine, other = by_depth, 1 - by_depth
        st = states[mine].copy()
        flipped = (mine == 0) != (d[0] <= d[1])  # depth gave the track the part away from its remembered centre
        st[4:] = 0.0 if flipped else tr.filt.estimate[4:6]
        tr.filt.set_state(st)
        lo = self.lost.pop(self._pick_lost(states[other], rgb))
        self._start(states[other], lo.id)
        new = self.tracks[-1]
        new.app, new.since_merge, new.apart = lo.app, 0, ESTABLISHED
        new.area_ref, new.centre_ref = tr.area_ref, states[other][:2].copy()
        tr.since_merge, tr.merged, tr.dup = 0, False, {}
        return lo.id

    def _depth_assignment(self, a: tuple[float, int], b: tuple[float, int], parts: list[np.ndarray],
                          d: list[float]) -> int | None:
        """Product addition (``depth_identity``, :mod:`tracker.hands.depth_order`): the part (0 or 1) of a 2-means
        split (``parts``: (N, 2) working pixels u, v each) that the track with remembered depth ``a`` = (z m, frame)
        takes by depth order against the track with ``b``, or None (off, no depth, a remembered depth older than
        DEPTH_MAX_AGE frames, or the depths too close to tell); ``d``: the distances of the two parts' centres from
        the first track's remembered centre, by which the image-only rule decides: depth decides only when these are
        within depth_order.IMAGE_SURE of each other (relative difference)."""
        if not self.config.depth_identity or self._depth is None:
            return None
        if abs(d[0] - d[1]) >= depth_order.IMAGE_SURE * max(d[0] + d[1], 1e-9):
            return None
        if self.frame_index - min(a[1], b[1]) > depth_order.DEPTH_MAX_AGE:
            return None
        zp = [depth_order.median_depth(self._depth, p[:, 0], p[:, 1], self.s) for p in parts]
        return depth_order.assign_by_depth((a[0], b[0]), (zp[0], zp[1]))

    def _largest_component(self, rgb: np.ndarray, b) -> np.ndarray | None:
        """Image pixels ``(N, 2)`` (u, v as floats) of the largest 4-connected component of this frame's colour mask
        inside the box ``b = [u0, v0, u1, v1]`` (inclusive, clipped to the image), or None when it holds none."""
        h, w = rgb.shape[:2]
        u0, v0, u1, v1 = max(b[0], 0), max(b[1], 0), min(b[2], w - 1), min(b[3], h - 1)
        if u1 <= u0 or v1 <= v0:
            return None
        sub = np.ascontiguousarray(self._frame_mask(rgb)[v0 : v1 + 1, u0 : u1 + 1])
        n, lab, stats, _ = cv2.connectedComponentsWithStats(sub, connectivity=4, ltype=cv2.CV_32S)
        if n < 2:
            return None
        ys, xs = np.nonzero(lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])))
        return np.column_stack([xs + u0, ys + v0]).astype(np.float64)

    def _split_shared(self, pair: tuple[int, int], rgb: np.ndarray) -> tuple[int, int] | None:
        """Product addition (``shared_split``): two hands that touch in one colour component while one track's box
        has grown over both and the other track sits inside it (on hands-s2: a hand came out from under the other, and
        its track had stayed on the top hand). Fires when the two tracks share a region (:meth:`_shared_pair`), both
        followed a hand of their own before (ESTABLISHED frames apart), the smaller box lies at least SPLIT_INSIDE
        inside the larger, the larger box has grown to REACQ_GROWTH times its one-hand area, and the dominant colour
        component under it holds at least SPLIT_SKIN of the two hands' one-hand colour-pixel counts (else the lower
        hand is still mostly hidden). The component is split by 2-means on pixel positions (each part at least
        REACQ_MIN_SHARE of it, each part's box at least SPLIT_MIN_PART of a one-hand area); the larger track takes the
        part nearer the centre it had while its box was one hand's size (``centre_one``: the hand it followed before
        its box grew), the smaller track the other part. Both filters restart on their parts' tight boxes with their
        ids and velocities; no id swap for SETTLE frames and no further split for SETTLE frames. Appearance does not
        decide here: while the hands touch, the box margins of both parts hold both sleeves. Returns the two ids, or
        None."""
        i, j = pair
        big, small = (self.tracks[i], self.tracks[j])
        if box_area(state_box(small.filt.estimate)) > box_area(state_box(big.filt.estimate)):
            big, small = small, big
        if big.area_apart <= 0 or big.apart < ESTABLISHED or small.apart < ESTABLISHED:
            return None
        if min(big.skin_apart, small.skin_apart) <= 0 or min(big.since_split, small.since_split) < SETTLE:
            return None
        b = state_box(big.filt.estimate)
        if box_area(b) < REACQ_GROWTH * big.area_apart:
            return None
        if inside_fraction(state_box(small.filt.estimate), b) < SPLIT_INSIDE:
            return None
        pts = self._largest_component(rgb, b)
        if pts is None:
            return None
        if len(pts) < SPLIT_SKIN * (big.skin_apart + small.skin_apart):
            return None  # not both hands' worth of skin: the lower hand is still mostly hidden
        parts = two_means(pts)
        if parts is None or min(len(p) for p in parts) < REACQ_MIN_SHARE * len(pts):
            return None
        states = [np.array([(p[:, 0].min() + p[:, 0].max()) / 2.0, (p[:, 1].min() + p[:, 1].max()) / 2.0,
                            np.ptp(p[:, 0]), np.ptp(p[:, 1]), 0.0, 0.0]) for p in parts]  # fmt: skip
        if min(box_area(state_box(st)) for st in states) < SPLIT_MIN_PART * min(big.area_apart, small.area_apart):
            return None  # a part smaller than a hand: one hand cut in two, or a hand still mostly hidden
        if big.centre_one is None:
            return None
        d = [float(np.hypot(*(st[:2] - big.centre_one))) for st in states]
        mine, other = (0, 1) if d[0] <= d[1] else (1, 0)
        by_depth = self._depth_assignment((big.z_apart, big.z_frame), (small.z_apart, small.z_frame), parts, d)
        if by_depth is not None:
            mine, other = by_depth, 1 - by_depth
        flipped = (mine == 0) != (d[0] <= d[1])  # depth gave the tracks the parts the image-only rule would not
        for tr, st in ((big, states[mine]), (small, states[other])):
            st = st.copy()
            st[4:] = 0.0 if flipped else tr.filt.estimate[4:6]
            tr.filt.set_state(st)
            tr.since_merge, tr.merged, tr.dup = 0, False, {}
            tr.hold_id = SETTLE  # the two hands still touch: no id swap until they have parted
            tr.skin_hist.clear()
            tr.since_split = 0
        return big.id, small.id

    def _covered(self, tr: _Track, feats: HandFeatures, size: tuple[int, int]) -> bool:
        """Whether a track's hand is going out of sight behind something, e.g. the other hand's arm (product addition,
        ``coast``), so that it moves on its velocity instead of following the shrinking visible part: the colour
        pixels in its predicted box (the estimate moved by its velocity) fall below COAST_DROP of the most seen over
        its last COAST_HISTORY frames; the predicted box inside the image (a hand leaving the image is not covered),
        overlapping no other track's box (two hands meeting are the blob split's case) and within COAST_NEAR box
        sizes of one (the arm that covers it belongs to the other hand); for at most COAST_MAX frames in a row. On
        the first covered frame the track is put back to its state on the frame of the most colour pixels, moved on
        by that frame's velocity (the visible part's box had already shrunk and slowed)."""
        e = tr.filt.estimate
        box = box_of(e[0] + e[4], e[1] + e[5], e[2], e[3])
        u0, v0, u1, v1 = box
        ox, oy = feats.roi[0], feats.roi[1]
        n, _ = mask_count(u0 - ox, v0 - oy, u1 - ox, v1 - oy, feats.mcur)
        inside = u0 >= 0 and v0 >= 0 and u1 < size[0] and v1 < size[1]
        others = [state_box(o.filt.estimate) for o in self.tracks if o is not tr]
        mx, my = COAST_NEAR * (u1 - u0 + 1), COAST_NEAR * (v1 - v0 + 1)
        near = (u0 - mx, v0 - my, u1 + mx, v1 + my)
        best = max(tr.hist, key=lambda h: h[0]) if tr.hist else None
        if (best is not None and n < COAST_DROP * best[0] and inside and tr.age >= ESTABLISHED
                and tr.coasting < COAST_MAX and others and not any(boxes_overlap(box, o) for o in others)
                and any(boxes_overlap(near, o) for o in others)
                and (not self.config.coast_depth or self._occluded(box, best[3]))):  # fmt: skip
            if not tr.coasting:
                st = best[1].copy()
                st[:2] += (self.frame_index - best[2]) * st[4:6]
                tr.filt.set_state(st)
            return True
        if tr.coasting:
            tr.hist.clear()
        z = float("nan")
        if self.config.coast_depth:
            b = box_of(e[0] - ox, e[1] - oy, e[2], e[3])
            z = depth_order.box_skin_depth(self._depth, feats.mcur, b, self.s, origin=(ox, oy))
        tr.hist.append((n, np.asarray(e, float).copy(), self.frame_index, z))
        return False

    def _occluded(self, box: tuple[int, int, int, int], z_hand: float) -> bool:
        """Product addition (``coast_depth``): whether something in front of the hand (nearer than its depth
        ``z_hand`` m by depth_order.OCCLUDER_GAP) fills at least depth_order.OCCLUDER_SHARE of the working box
        ``box`` (its predicted box), e.g. the other hand's arm; False without depth."""
        share = depth_order.nearer_share(self._depth, box, z_hand, self.s)
        return bool(np.isfinite(share) and share >= depth_order.OCCLUDER_SHARE)

    def _collect_adapt_pixels(self, rgb: np.ndarray, mcur: np.ndarray, roi: tuple[int, int, int, int]) -> None:
        """Skin samples for the session adaptation: the colour-mask pixels inside a confident (a_{c,1} ≥ 0.5)
        track's box that are not on the mask's edge (3×3 erosion: edge pixels blend skin with sleeve or table), only
        for tracks whose box expanded by half its size meets no other track's box (two hands together may hold a
        wrong box); at most 200 per track and frame, kept over the last ``adapt_every`` frames."""
        x0, y0, x1, y1 = roi
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        for i, tr in enumerate(self.tracks):
            if tr.score < 0.5 or tr.merged:
                continue
            b = boxes[i]
            mx, my = 0.5 * (b[2] - b[0] + 1), 0.5 * (b[3] - b[1] + 1)
            big = (b[0] - mx, b[1] - my, b[2] + mx, b[3] + my)
            if any(boxes_overlap(big, boxes[j]) for j in range(len(boxes)) if j != i):
                continue
            u0, v0, u1, v1 = b
            a0, b0 = max(u0 - x0, 0), max(v0 - y0, 0)
            a1, b1 = max(min(u1 + 1, x1) - x0, 0), max(min(v1 + 1, y1) - y0, 0)
            if a1 - a0 < 3 or b1 - b0 < 3:
                continue
            inner = cv2.erode(mcur[b0:b1, a0:a1], np.ones((3, 3), np.uint8)).astype(bool)
            px = rgb[y0:y1, x0:x1][b0:b1, a0:a1][inner]
            if len(px):
                self._adapt_pixels.append(px[:: max(1, len(px) // 200)])

    def _reseed(self, feats: HandFeatures, size: tuple[int, int]) -> None:
        """Product addition (particle filter): a track whose box covers part of a hand-sized colour component that no
        other track's box touches is offered the component's tight box (HandParticleFilter.reseed; the likelihood
        decides). The section-6 test needs the box to hold 80 % of the component already, so a box that has shrunk
        to a sliver of its hand, or grown over the table, never comes back by it. Hand-sized: the component's
        longer side ≤ RESEED_HAND_M at its median depth (0.75 m without depth); not cut by the ROI edge; holding
        RESEED_SHARE of the box's colour pixels; not for a track on a wrist-cut anchor."""
        ox, oy = feats.roi[0], feats.roi[1]
        boxes = [box_of(tr.filt.estimate[0] - ox, tr.filt.estimate[1] - oy, tr.filt.estimate[2], tr.filt.estimate[3])
                 for tr in self.tracks]  # fmt: skip
        min_area = self.config.min_area_frac * size[0] * size[1]
        for i, tr in enumerate(self.tracks):
            if not isinstance(tr.filt, HandParticleFilter) or tr.merged or tr.coasting:
                continue
            lab, cnt = dominant_component(*boxes[i], feats.cc, feats.n_comp)
            if lab == 0 or feats.cc_cut[lab] or feats.cc_area[lab] < min_area:
                continue
            u0, v0, u1, v1 = (max(v, 0) for v in boxes[i])
            if cnt < RESEED_SHARE * np.count_nonzero(feats.mcur[v0 : v1 + 1, u0 : u1 + 1]):
                continue  # the box's skin is not mostly this one component (a hand beside a skin-like part)
            if len(feats.anchors) and match_anchor(np.array([state_box(tr.filt.estimate)], np.float64),
                                                   feats.anchors)[0] >= 0:  # fmt: skip
                continue  # the wrist cut holds this track
            cb = tuple(int(v) for v in feats.cc_box[lab])
            if box_f_score(cb, boxes[i]) >= RESEED_F:
                continue
            if any(boxes_overlap(cb, boxes[j]) for j in range(len(boxes)) if j != i):
                continue
            z = self._component_depth(feats, lab)
            if max(cb[2] - cb[0], cb[3] - cb[1]) > self._focal_px() / self.s * RESEED_HAND_M / z:
                continue
            e = tr.filt.estimate
            cx, cy = 0.5 * (cb[0] + cb[2]) + ox, 0.5 * (cb[1] + cb[3]) + oy
            state = np.array([cx, cy, cb[2] - cb[0], cb[3] - cb[1], e[4], e[5]], float)
            tr.filt.reseed(state, feats)

    def _component_depth(self, feats: HandFeatures, lab: int) -> float:
        """Median valid depth (m) of a colour component of the features' ROI (0.75 m without depth)."""
        if self._depth is None:
            return 0.75
        ys, xs = np.nonzero(feats.cc == lab)
        ys, xs = ys[::7] + feats.roi[1], xs[::7] + feats.roi[0]
        d = np.asarray(self._depth)
        z = d[np.minimum(ys * self.s, d.shape[0] - 1), np.minimum(xs * self.s, d.shape[1] - 1)]
        z = z[np.isfinite(z) & (z > 0)]
        return order_stats.median(z) if len(z) else 0.75

    def _end(self, ending: list[bool]) -> None:
        """Tracks flagged in ``ending`` become lost tracks (re-acquirable with their ids) if ``reacquire``."""
        if not self.config.reacquire:
            return
        for tr, e in zip(self.tracks, ending, strict=True):
            if e:
                self.lost.append(_Lost(tr.id, np.asarray(tr.filt.estimate, float).copy(), app=tr.app,
                                       z_apart=tr.z_apart, z_frame=tr.z_frame))

    def _estimate(self, tr: _Track, size: tuple[int, int], feats: HandFeatures | None = None) -> HandEstimate:
        f = tr.filt
        e = f.estimate
        if feats is not None:
            ox, oy = feats.roi[0], feats.roi[1]
            u0, v0, u1, v1 = box_of(e[0] - ox, e[1] - oy, e[2], e[3])
            obs = box_observation(u0, v0, u1, v1, feats.mcur, feats.labb[0], feats.labb[1], self.config.n_clusters,
                                  self.pf_params.d2_scale)  # fmt: skip
            tr.score = float(obs[0])
        n = self.config.n_particles if isinstance(f, HandParticleFilter) else 1
        full = self.to_full(e)
        assert self.full_size is not None
        return HandEstimate(tr.id, full, clipped_box(full, self.full_size), tr.score, f.n_eff / n, f.det_fraction)

    def _terminate(self, size: tuple[int, int]) -> list[bool]:
        cfg = self.config
        keep = [True] * len(self.tracks)
        boxes = [state_box(tr.filt.estimate) for tr in self.tracks]
        for i, (tr, b) in enumerate(zip(self.tracks, boxes, strict=True)):
            full = box_area(b)
            iw = min(b[2], size[0] - 1) - max(b[0], 0) + 1
            ih = min(b[3], size[1] - 1) - max(b[1], 0) + 1
            inside = max(iw, 0) * max(ih, 0)
            if full <= 0 or inside < 0.5 * full:
                keep[i] = False
            tr.low = tr.low + 1 if tr.score < 0.2 and not tr.coasting else 0
            tr.tiny = tr.tiny + 1 if full < cfg.min_area_frac * size[0] * size[1] else 0
            if tr.low >= cfg.n_lost or tr.tiny >= cfg.n_lost:
                keep[i] = False
            if EXIT_END and keep[i] and self._left_image(b, size):
                keep[i] = False
        fs = np.zeros((len(boxes), len(boxes)))
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                fs[i, j] = fs[j, i] = box_f_score(boxes[i], boxes[j])
        for i, tr in enumerate(self.tracks):
            tr.apart = tr.apart + 1 if all(fs[i, j] < APART_F for j in range(len(boxes)) if j != i) else tr.apart
            tr.since_merge += 1
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = self.tracks[i], self.tracks[j]
                if fs[i, j] >= 0.8:
                    a.dup[b.id] = a.dup.get(b.id, 0) + 1
                    # two tracks that each followed a hand of their own before are two hands on top of each other:
                    # both stay (ids frozen) until the hands part or a free hand turns up (_transfer)
                    two_hands = a.apart >= ESTABLISHED and b.apart >= ESTABLISHED
                    a.merged = b.merged = two_hands
                    both_found = ARM_KEEP_MERGED and two_hands and {a.id, b.id} <= self._arm_own
                    if a.dup[b.id] >= (MERGED_KEEP if two_hands else cfg.n_lost) and not both_found:
                        keep[self._duplicate_loser(i, j)] = False
                elif fs[i, j] < APART_F:
                    a.dup.pop(b.id, None)
        for i, tr in enumerate(self.tracks):
            if tr.merged and not any(fs[i, j] >= APART_F for j in range(len(boxes)) if j != i):
                tr.merged = False
            if tr.merged:
                tr.since_merge = 0
        return keep

    def _left_image(self, b: tuple[int, int, int, int], size: tuple[int, int]) -> bool:
        """Whether a track's inclusive working box ``b`` reaches the image border (within b = 2 full px, as for a
        candidate) and holds no pixel of this frame's colour mask (``EXIT_END``): its hand has left the image."""
        if not touches_border(b, size, border_band(self.s)):
            return False
        assert self._cur_rgb is not None
        n, _ = mask_count(b[0], b[1], b[2], b[3], self._frame_mask(self._cur_rgb))
        return n == 0

    # ------------------------------------------------------------------ automatic initialisation
    def _auto_init(self, rgb: np.ndarray, depth: np.ndarray | None, reacquire: bool = False,
                   ignore: list[_Track] | tuple = ()) -> np.ndarray | None:  # fmt: skip
        """A new track's initial working-resolution state, or None (see the module docstring). With ``reacquire``
        (a lost track waits for its hand) a candidate need not touch the image border when first seen if its box
        centre has moved by ≥ :data:`REACQUIRE_MOVE` working px over its n_init frames (a moving skin region that no
        track explains)."""
        cfg = self.config
        h, w = rgb.shape[:2]
        mask = self._frame_mask(rgb)
        r = max(1, int(round(2.0 / self.s)))
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, disk)
        n, lab, stats, (ox, oy) = cropped_components(mask)
        min_area = cfg.min_area_frac * w * h
        b = border_band(self.s)
        track_boxes = [state_box(tr.filt.estimate) for tr in self.tracks if not any(tr is t for t in ignore)]
        found: list[tuple[int, tuple[int, int, int, int], int, bool]] = []
        for i in range(1, n):
            area = int(stats[i, cv2.CC_STAT_AREA])
            if area < min_area:
                continue
            bx, by, bw, bh = (int(v) for v in stats[i, :4])
            box = (bx, by, bx + bw - 1, by + bh - 1)
            if track_boxes:
                comp = lab[by - oy : by - oy + bh, bx - ox : bx - ox + bw] == i
                covered = np.zeros_like(comp)
                for tb in track_boxes:
                    a0, b0 = max(tb[0] - bx, 0), max(tb[1] - by, 0)
                    a1, b1 = min(tb[2] - bx + 1, bw), min(tb[3] - by + 1, bh)
                    if a1 > a0 and b1 > b0:
                        covered[b0:b1, a0:a1] = True
                if np.count_nonzero(comp & covered) > 0:
                    continue
            border = touches_border(box, (w, h), b)
            found.append((area, box, i, border))
        cands: list[_Candidate] = []
        best: tuple[int, int, _Candidate] | None = None
        for area, box, i, border in found:
            centre = (0.5 * (box[0] + box[2]), 0.5 * (box[1] + box[3]))
            prev = [c for c in self._candidates if boxes_overlap(c.box, box)]
            if prev:
                p = max(prev, key=lambda c: c.seen)
                c = _Candidate(box, p.seen + 1, p.border, p.first)
            else:
                c = _Candidate(box, 1, border, centre)
            cands.append(c)
            moved = float(np.hypot(centre[0] - c.first[0], centre[1] - c.first[1])) >= REACQUIRE_MOVE
            if not (c.border or (reacquire and moved)):
                continue
            if c.seen >= cfg.n_init and (best is None or area > best[0]):
                best = (area, i, c)
        self._candidates = cands
        if best is None:
            return None
        _, i, c = best
        self._candidates = [x for x in cands if x is not c]
        comp = np.zeros((h, w), bool)
        comp[oy : oy + lab.shape[0], ox : ox + lab.shape[1]] = lab == i
        return self._initial_state(comp, depth)

    def _initial_state(self, comp: np.ndarray, depth: np.ndarray | None) -> np.ndarray:
        """Palm box (working resolution) of a border-entering component: its pixels within L_hand of its far end."""
        cut = palm_cut(comp, depth, self.s, self._focal_px(), self.config.hand_length_m, tube=self._tube())
        u0, v0, u1, v1 = cut.box
        if not cut.has_forearm:  # no forearm in the component (sleeve): the whole component
            ys, xs = np.nonzero(comp)
            u0, v0, u1, v1 = int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())
        return np.array([(u0 + u1) / 2.0, (v0 + v1) / 2.0, float(u1 - u0), float(v1 - v0), 0.0, 0.0])

    def _tube(self) -> tuple[float, float] | None:
        """(reach, tip) in metres of the tube cut of an arm (:func:`tracker.hands.palm_cut.tube_cut`), None if off."""
        cfg = self.config
        return (cfg.palm_reach_m, cfg.palm_tip_m) if cfg.palm_tube else None

    def _focal_px(self) -> float:
        """Focal length in full-resolution pixels (0.82·width without intrinsics)."""
        assert self.full_size is not None
        return float(self.focal) if self.focal else 0.82 * self.full_size[0]


@nb.njit(cache=True, nogil=True)
def _roi_bounds(states, margin, x0, y0, x1, y1):
    """(x0, y0, x1, y1) grown to hold every state's inclusive box (:func:`box_of`) expanded by ``margin``: per box
    ``x0 = min(x0, int(u0 − margin))``, ``x1 = max(x1, int(u1 + margin) + 1)`` (int truncates towards zero, as
    Python's), the same for y."""
    for i in range(states.shape[0]):
        u0, v0, u1, v1 = box_of(states[i, 0], states[i, 1], states[i, 2], states[i, 3])
        x0 = min(x0, int(u0 - margin))
        y0 = min(y0, int(v0 - margin))
        x1 = max(x1, int(u1 + margin) + 1)
        y1 = max(y1, int(v1 + margin) + 1)
    return x0, y0, x1, y1


def _snapshot(filt: HandParticleFilter | HandKalmanFilter) -> dict:
    """A filter's attributes, arrays copied (to put a filter back after a step)."""
    return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in filt.__dict__.items()}
