"""Each hand at the far end of its own arm (product addition, ``HandTrackerConfig.arm_anchor``).

Two hands that touch or lie on each other form one skin region in which neither colour nor flow tells them apart,
and the two particle filters then split it side by side or both sit on one hand. But each hand is the far end of an
arm that enters the image from its border, and the two arms seldom swap where they enter. This module finds, per
frame and without tracking, each arm and the skin pixels at its end:

1. Foreground: the pixels nearer the camera than the session's first (hand-free) depth frame by :data:`FG_GAP`, or
   without depth where that frame had depth (an arm too near the sensor); opened with a 3×3 square. More than
   :data:`MAX_FG_FRAC` of the frame in front of the background: the camera has moved (or the first frame held a
   hand), and nothing is found.
2. Arms: the 8-connected components of the foreground without the (dilated) skin mask — the sleeves — of at least
   :data:`MIN_ARM_FRAC` of the image that touch the image border in one run. The entry point is the mean of its
   border pixels. A component that meets the border in two runs is two forearms crossing (the sleeves touch where
   one lies over the other): while the one-run components give fewer than two arms, it is split by a tube per run
   (:data:`CROSS_SPLIT`, :func:`_crossed_seeds`), unless both tubes' wrists reach one skin region.
3. Wrist: the sleeve pixels whose straight-line distance from the arm's entry point is at least :data:`WRIST_FAR`
   of the farthest and that lie next to skin; the skin pixels next to them seed the hand.
4. Hands: one multi-source geodesic distance over the skin mask from all arms' seeds at once (Dijkstra, 4-neighbour
   steps of cost 1, plus :data:`DEPTH_STEP_COST` across a depth step larger than :data:`DEPTH_STEP` m: the edge of the
   upper hand over the lower one; also into or out of a skin pixel without depth, :data:`HOLE_STEP`, the sensor's blind
   band along that edge; and :data:`KEEP_COST` per pixel into a skin pixel that the previous frame's split gave another
   arm, when the tracker ran this detector on the previous frame too, whose wrist seeds in such pixels are dropped,
   :data:`SEED_VETO`; wrist seeds whose skin does not lie behind the sleeve beside them, another hand lying over the
   sleeve's end, are dropped too, :data:`SEED_BEHIND`; an arm whose hand the other arm's label took since the previous
   frame can get its previous pixels as seeds, :data:`STOLEN_RESEED`, off); each skin pixel belongs to the arm whose
   wrist reaches it first. Crossing a grey-level edge costs extra too (:data:`EDGE_SPLIT`: two hands of one tone still
   differ in shading where they meet). With the frame's optical flow (:data:`MOTION_SPLIT`, on) two arms' split is run
   again with the two hands' motions as a prior: a skin pixel whose flow clearly follows one hand's motion costs the
   other arm's label :data:`MOTION_COST` per pixel (:func:`motion_prior`). A hand's box is the tight box of its pixels
   (at least :data:`MIN_HAND_PX`) and of the unopened mask's skin within :data:`RIM_PX` of them (:data:`BOX_RIM`).

Without depth nothing is found. Dev measurement (``hands-s2`` tuning seeds 0–4, this detector alone, no tracking,
the left entry taken as one hand): per hand-frame F̄^b 0.76 / 0.85 / 0.66 / 0.83 / 0.55; used where it finds the
track's arm, the tracker's box otherwise, 0.714 → 0.814 over filter seeds 0–3 (every run but one better). In the
tracker (:meth:`tracker.hands.tracker.HandTracker._report_arms`) see its module docstring. Not handled: crossing
arms whose hands touch (a nearest-axis split of the whole X, tried in session 17, gave the far ends to the wrong
arms; the tubes of session 27 fit each axis near its own entry), an arm entering through the top border while the
other fills the bottom one, an arm mostly out of view (below :data:`MIN_ARM_FRAC`), arms of the same colour as skin
(bare forearms: no sleeve, nothing found), a moving camera (the first frame's depth is the background).

Images are at the tracker's working resolution; boxes inclusive working px [u0, v0, u1, v1]; depth in metres.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from tracker.hands import order_stats

FG_GAP = 0.02
"""Metres a pixel must lie nearer the camera than the background depth to be foreground (arm, hand)."""
MAX_FG_FRAC = 0.5
"""Largest foreground share (of the pixels with background depth) for which the background frame is trusted."""
MIN_ARM_FRAC = 300 / (320 * 240)
"""Smallest sleeve component, as a share of the working image, that counts as an arm."""
BORDER_PX = 2
"""Working px from the image edge within which a sleeve pixel is an entry pixel."""
RUN_GAP = 8.0
"""Gap (working px along the image border) that splits a component's border pixels into separate runs."""
MIN_RUN = 6
"""Fewest border pixels of a run."""
WRIST_FAR = 0.9
"""Share of the farthest distance from the arm's entry point beyond which a sleeve pixel next to skin is wrist (0.7
in session 17). hands-s2 tuning seeds 0–4, ground-truth start, paired: 0.7 → 0.8 F̄^b 0.8246 → 0.8272, ē^p 11.75 →
11.48 px on filter seeds 0–3, 0.8198 → 0.8251, 11.59 → 11.03 px on 4–7; 0.8 → 0.9 0.8272 → 0.8384, 11.48 → 10.84 px
and 0.8251 → 0.8337, 11.03 → 10.60 px, no run worse by 0.005 in either step; 0.95 on filter seeds 0, 1: 0.8397 →
0.8431 but seed 2 worse in both runs (−0.014, −0.020), not kept. A sleeve that also touches skin nearer its entry
(e.g. the other hand lying on it) seeds less of that hand."""
DEPTH_STEP = 0.008
"""Depth difference (m) between 4-neighbours that counts as a step (the edge of the upper hand; 0.012 until session
25, see :data:`DEPTH_STEP_COST`)."""
DEPTH_STEP_COST = 40.0
"""Extra geodesic cost (working px) of crossing a depth step (20 until session 25). Session 25, this detector alone on
the inputs of its calls in ``hands-s2`` tuning seeds 0–4 (ground-truth start, filter seed 0; each hand box matched
to a ground-truth box, per hand-frame F^b on frames where the two hands' boxes overlap by F ≥ 0.3): 0.012 m / 20
0.8445, 0.012 / 40 0.8507, 0.008 / 20 0.8490, 0.008 / 40 0.8568, 0.006 / 40 0.8580, 0.008 / 30 0.8554, 0.008 / 60
0.8542, 0.01 / 40 0.8517: a flat hand on a flat hand is about a centimetre above it. In the tracker see
``benchmarks/history/issue-14-hands.md``."""
MIN_HAND_PX = 20
"""Fewest skin pixels (working px) a hand must get to be reported."""
HOLE_STEP = True
"""Whether a skin pixel without depth counts as a depth step for the geodesic split: stepping into or out of it costs
:data:`DEPTH_STEP_COST` (a depth sensor has no depth along an occluding edge, so the edge of the upper hand over the
lower one is a band of unknown depth, which the two-sided step test never sees; in the simulator's ``hands-s2`` the
4-neighbour pairs across the two hands' boundary had no depth on a side in most cases). Session 19, ``hands-s2``
tuning seeds 0–4, ground-truth start: F̄^b 0.8409 → 0.8637, ē^p 10.05 → 8.46 px (filter seed 0), 0.8382 → 0.8629,
10.49 → 8.69 px (filter seed 1), every sequence better in both; automatic start 0.853 → 0.872, 9.37 → 8.00 px, missed
hands 1.6 % both, false boxes 0.0218 → 0.0224 per frame; ``hands-s1`` and ``hands-s3`` unchanged. Band grown by 0 px:
0.8594, by 2 px: 0.8418 (filter seed 0); :data:`DEPTH_STEP_COST` 10 / 40 with it: 0.8552 / 0.8665 (not changed)."""
HOLE_GROW = 1
"""Working px by which the pixels without depth are grown (a square) before :data:`HOLE_STEP` marks the skin pixels
among them: at the working resolution a band of one or two full-resolution pixels has gaps."""
KEEP_COST = 3.0
"""Extra geodesic cost (working px per pixel) of spreading an arm's label into a skin pixel that the previous frame's
split gave the other arm (``prev`` of :func:`arm_split`; 0: every frame split afresh, as until session 26): where two
touching hands meet, the split keeps last frame's labels unless the wrists' distances clearly say otherwise. Session
26, ``hands-s2`` tuning seeds 0–4, the same frames for both arms, 0 → 3: ground-truth start F̄^b 0.8778 → 0.8816, ē^p
7.61 → 7.32 px (filter seed 0), 0.8758 → 0.8802, 7.94 → 7.60 px (filter seed 1); automatic start 0.8857 → 0.8892,
6.78 → 6.49 px (filter seed 0), 0.8827 → 0.8861, 7.03 → 6.75 px (filter seed 1); 16 of 20 runs better, seed 1 worse
by 0.001–0.003 in all four. 1: 0.8787, 2: 0.8803, 5: 0.8805 (ground-truth start, filter seeds 0 / 0 / 1)."""
KEEP_ENTRY_NEAR = 24.0
"""Working px an arm's entry point may lie from one of the previous frame's for its labels to carry over."""
CROSS_SPLIT = True
"""Whether a sleeve component that meets the image border in two runs (two forearms crossing) is split into two arms
by a tube per run (:func:`_crossed_seeds`), when the components with one run gave fewer than two arms (new in session
27; before, no arm was found there: on ``hands-s2`` tuning seeds 0, 2, 4 most frames where the hands do not touch).
This detector alone on the inputs of its calls in ground-truth-start runs of ``hands-s2`` tuning seeds 0–4 (filter
seed 0), per hand-frame F^b on the frames whose two ground-truth boxes overlap by F < 0.05: 0.556 → 0.860 (seed 0
0.583 → 0.941, 2 0.452 → 0.736, 4 0.262 → 0.853; seeds 1, 3 unchanged); touching (F ≥ 0.3) 0.839 → 0.843. In the
tracker see ``benchmarks/history/issue-14-hands.md``."""
CROSS_TOUCH_DROP = True
"""Whether the two tubes of a crossing are dropped when their wrists seed one 8-connected skin region (touching
hands; :func:`_crossed_seeds`)."""
BOX_RIM = True
"""Whether a hand's box also covers the skin pixels of the unopened colour mask within :data:`RIM_PX` of its pixels
(new in session 28): the split runs on the mask opened by a 3 × 3 cross, which trims the hand's rim and drops its
parts narrower than 3 px, and its tight box fell short of the rendered palm box (ground-truth start, ``hands-s2``
tuning seeds 0–4, filter seed 0, frames with F^b ≥ 0.85: its wrist and finger edges 0.9–1.0 full px inside the ground
truth's on average). In the tracker, the same frames for both arms, off → on (with RIM_PX 1): F̄^b 0.8828 → 0.8877
ground-truth start (filter seeds 0–2), 0.8888 → 0.8928 automatic start, KF 0.8852 → 0.8896; 35 of 35 runs better;
``hands-s1``, ``hands-s3`` identical."""
RIM_PX = 1
"""Working px (Chebyshev distance) from a hand's pixels within which :data:`BOX_RIM` takes the unopened mask's skin.
2 (session 28, paired against 1 as for :data:`BOX_RIM`): F̄^b 0.8877 → 0.8888 ground-truth start (filter seeds
0–2), 0.8928 → 0.8940 automatic start, KF 0.8896 → 0.8901, but automatic start missed hands 0.06 % → 0.45 % (seed 3,
filter seed 1: 5.9 % of its hand-frames) and false boxes 0.0034 → 0.0045 per frame, ē^p automatic start 6.44 → 6.48,
KF 6.77 → 6.87 px: not taken."""
TUBE_R0 = 40.0
"""Working px from a run's entry point where the pixels that give its tube's direction begin (the detector alone as
for :data:`CROSS_SPLIT`, seeds 0, 2, 4, frames apart: 15 / 60 px 0.671, 15 / 40 0.543, 15 / 90 0.814, 15 / 120
0.856, 15 / 160 0.811, 40 / 90 0.859; TUBE_GROW 1.0 / 1.7 at 15 / 60: 0.667 / 0.672)."""
TUBE_R1 = 90.0
"""Working px from a run's entry point where the pixels that give its tube's direction end."""
TUBE_GROW = 1.3
"""Factor on a tube's radius within which a pixel may belong to it (:func:`_crossed_seeds`)."""
HOLE_DEPTH = 1e3
"""Depth (m) given to the skin pixels without depth when :data:`HOLE_STEP` is on: far from every measured depth."""
MOTION_SPLIT = True
"""Whether the split of two arms' skin is redone with each pixel's optical flow as a prior (:func:`motion_prior`;
``flow`` of :func:`arm_split`): the two hands move differently even where they touch, so the skin pixels whose flow
clearly follows one hand's motion cost the other arm's label :data:`MOTION_COST` per pixel to spread into (new in
session 29; on: F̄^b, ē^p and false boxes better, missed hands by about 2 hand-frames of 14 500 more often with
automatic start, 27 times below the target's 2 %). On the detector's calls in
``hands-s2`` tuning seeds 0–4 (ground-truth start, filter seed 0) the skin of each hand's box outside the other's
follows its own hand's median flow rather than the other's in 94–98 % of the pixels, also where the two motions
differ by only 0.2–0.5 working px a frame (flow spread within a hand 0.05–0.1 px). In the tracker, ``hands-s2``
tuning seeds 0–4, the same frames for both arms, off → on: ground-truth start F̄^b 0.8887 → 0.8925, ē^p 6.85 → 6.56
px (filter seed 0), 0.8872 → 0.8917, 6.96 → 6.56 px (filter seeds 1, 2); automatic start 0.8937 → 0.8967 (filter
seed 0), 0.8924 → 0.8970 (1, 2), 0.8933 → 0.8965 (3, 4), over filter seeds 0–4 missed hands 0.059 % → 0.073 % (about
2 of 14 500 hand-frames, seed 4), false boxes 0.0037 → 0.0034 per frame; KF 0.8896 → 0.8917; seed 4 worse in 3 of 7
runs of filter seeds 0–2 (by up to 0.005); ``hands-s1``, ``hands-s3`` identical (the prior never acts there). The
detector's call 2.4 → 4.1 ms thread CPU where it finds two arms (the second geodesic pass);
``benchmarks/history/issue-14-hands.md``."""
MOTION_SEP = 0.15
"""Least distance (working px per frame) between the two hands' motions (the two flow clusters' centres) for
:data:`MOTION_SPLIT` to act."""
MOTION_MARGIN = 0.2
"""Share of the distance between the two motions by which a pixel's flow must lie nearer one of them (projected on
the line between them: below 0.5 − margin or above 0.5 + margin) to be given to that hand."""
MOTION_COST = 3.0
"""Extra geodesic cost (working px per pixel) of spreading an arm's label into a skin pixel whose flow follows the
other arm's hand (:data:`MOTION_SPLIT`); in that second pass the previous split's labels count where the flow does
not decide, at this cost too. 8 with the previous split left out of the second pass (session 29, ``hands-s2`` tuning
seeds 0–4, ground-truth start, filter seed 0): F̄^b 0.8923 against 0.8925 at 3."""
EDGE_SPLIT = True
"""Whether the geodesic split also pays for crossing a grey-level edge (``grey`` of :func:`arm_split`):
:data:`EDGE_SLOPE` working px per grey level by which two 4-neighbours differ by more than :data:`EDGE_THR` (new in
session 31, on). Two hands of one person have one skin tone, but where one lies on or beside the other their shading
changes across the boundary (another surface orientation, a shadow): on the detector's two-arm calls in ``hands-s2``
tuning seeds 0–4 (ground-truth start, filter seed 0) the 4-neighbour skin pairs across the two hands' boundary differ
by a median 40 grey levels of the working image against 6 within a hand (79 % of them above the within-hand 90th
percentile, 20); the depth step of :data:`DEPTH_STEP` separates fewer (54 % of those pairs have no depth on a side, of
the rest about half lie above the within-hand 90th percentile). The detector alone on those calls, lost F^b of its
arm boxes 286.0 → 228.2 (every seed better). In the tracker, ``hands-s2`` tuning seeds 0–4, the same frames for both
arms, off → on, filter seeds 0 / 1 / 2 / 3 / 4: ground-truth start F̄^b 0.8967 / 0.8943 / 0.8976 / 0.8973 / 0.8964
→ 0.9159 / 0.9150 / 0.9119 / 0.9143 / 0.9137, ē^p 6.38 / 6.48 / 6.27 / 6.30 / 6.36 → 5.08 / 5.14 / 5.45 / 5.16 / 5.22
px; automatic start 0.9009 / 0.9003 / 0.9020 / 0.8998 / 0.9014 → 0.9185 / 0.9176 / 0.9201 / 0.9174 / 0.9188, ē^p
5.97 / 6.00 / 5.87 / 6.04 / 5.90 → 4.79 / 4.87 / 4.70 / 4.90 / 4.78 px, missed hand-frames 11 → 9 of 15 855, false
boxes 30 → 43 of 8955 frames (0.0034 → 0.0048 per frame); 49 of 50 runs better (ground-truth start filter seed 2,
seed 2 −0.002); KF (ground-truth start) 0.8960 → 0.9148, ē^p 6.40 → 5.17 px; ``hands-s1`` and ``hands-s3``
identical (the detector runs only with two tracks). ``benchmarks/history/issue-14-hands.md``."""
EDGE_THR = 10
"""Grey levels (0–255, the working image) by which two 4-neighbours may differ before :data:`EDGE_SPLIT` charges."""
EDGE_SLOPE = 4
"""Extra geodesic cost (working px) per grey level above :data:`EDGE_THR` (:data:`EDGE_SPLIT`). 8 (paired as for
:data:`EDGE_SPLIT`, filter seeds 0–4): F̄^b about as 4 (ground-truth start 0.9151 / 0.9163 / 0.9149 / 0.9139 / 0.9132,
automatic start 0.9181 / 0.9176 / 0.9202 / 0.9193 / 0.9200), but missed hand-frames 11 → 13 and false boxes 30 → 47;
the detector alone (lost F^b of its arm boxes, thr 10): slope 2 234.4, 4 228.2, 8 225.5, 16 224.3."""
SEED_VETO = True
"""Whether an arm's wrist seeds that the previous split (``prev`` of :func:`arm_split`) gave another arm are dropped
before the geodesic split (an arm keeps all its seeds if none would be left): a sleeve running along the other hand's
edge seeds that hand, and a seed costs nothing, so :data:`KEEP_COST` never acts against it (new in session 32, on).
``hands-s2`` tuning seeds 0–4, the same frames for both arms, off → on, filter seeds 0 / 1 / 2 / 3 / 4: ground-truth
start F̄^b 0.9159 / 0.9150 / 0.9119 / 0.9143 / 0.9137 → 0.9161 / 0.9144 / 0.9149 / 0.9159 / 0.9151, ē^p 5.08 / 5.14 /
5.45 / 5.16 / 5.22 → 5.06 / 5.20 / 5.19 / 5.04 / 5.13 px (mean 0.9142 → 0.9153, 5.21 → 5.12 px; 18 of 25 runs
better, 7 worse); automatic start 0.9185 / 0.9176 / 0.9201 / 0.9174 / 0.9188 → 0.9193 / 0.9182 / 0.9212 / 0.9183 /
0.9203, ē^p 4.79 / 4.87 / 4.70 / 4.90 / 4.78 → 4.75 / 4.81 / 4.60 / 4.79 / 4.65 px (mean 0.9185 → 0.9195, 4.81 → 4.72
px; 20 of 25 runs better), missed hand-frames 9 / 9 of 15 855, false boxes 10 → 9 of 8955 frames; ``hands-s1`` and
``hands-s3`` identical (filter seed 0, both starts). The detector alone on its calls of ground-truth-start runs
(filter seed 0, the previous split as the tracker had it), lost F^b of its arm boxes 225.9 → 224.6: it acts mostly
through the chained splits. Cost: 2.91–3.02 → 3.07–3.18 ms thread CPU a detector call (seed 2's calls, three
alternated passes, load 9). ``benchmarks/history/issue-14-hands.md``."""
SEED_BEHIND = True
"""Whether an arm's wrist seeds whose skin does not lie behind its sleeve are dropped before the geodesic split (an arm
keeps all its seeds if none would be left; new in session 33, on): at a cuff the sleeve covers the wrist, so the
own hand's skin next to the sleeve's end lies behind the sleeve, while another hand lying over the sleeve's end (a
hand folded under the other, only a finger of it showing past the upper hand) lies at the sleeve's depth or in front,
and its edge would seed this arm. Per seed pixel, the median of the known depths of the skin pixels and of the sleeve
pixels within :data:`BEHIND_R` working px (a square); a seed whose skin median is less than :data:`BEHIND_GAP` behind
the sleeve median goes (one side without depth: it stays). ``hands-s2`` tuning seeds 0–4, the same frames for both
arms, off → on, filter seeds 0 / 1 / 2 / 3 / 4: ground-truth start F̄^b 0.9161 / 0.9144 / 0.9149 / 0.9159 / 0.9151 →
0.9181 / 0.9176 / 0.9164 / 0.9200 / 0.9186, ē^p 5.06 / 5.20 / 5.19 / 5.04 / 5.13 → 4.95 / 4.97 / 5.07 / 4.76 / 4.89 px
(mean 0.9153 → 0.9181, 5.12 → 4.93 px); automatic start 0.9193 / 0.9182 / 0.9212 / 0.9183 / 0.9203 → 0.9227 / 0.9207
/ 0.9229 / 0.9218 / 0.9219 (mean 0.9195 → 0.9220, ē^p 4.72 → 4.54 px), missed hand-frames 9 / 9 of 15 855, false
boxes 9 → 10 of 8955 frames; per sequence (mean of filter seeds) ground-truth start 0.9517 → 0.9512, 0.9179 → 0.9266,
0.9007 → 0.9032, 0.9483 → 0.9502, 0.8580 → 0.8593 (seed 1 frames 280–298, a hand folded under the other: lost F^b 8.7
→ 4.4 units); ``hands-s1``, ``hands-s3`` identical (filter seed 0, both starts). Cost 0.22 ms thread CPU a detector
call (load 17). ``benchmarks/history/issue-14-hands.md``."""
BEHIND_GAP = 0.005
"""Metres the skin next to a wrist seed must lie behind the sleeve beside it (:data:`SEED_BEHIND`). The detector alone
on its calls of ground-truth-start runs of ``hands-s2`` tuning seeds 0–4 (lost F^b of its arm boxes, 224.6 without;
:data:`BEHIND_R` 3): 2 mm (seeds 1, 4) 122.7 against 124.2, 4 mm 216.2, 5 mm 215.1, 6 mm 214.9, 8 mm 222.9, 12 mm
254.9; R 2 at 5 mm 214.3 (every seed better), R 5 at 8 mm (seeds 1, 4) 123.1."""
BEHIND_R = 2
"""Half side (working px) of the square around a wrist seed in which :data:`SEED_BEHIND` compares depths."""
STOLEN_RESEED = False
"""Whether an arm whose hand the other arm's label took from one frame to the next gets its previous pixels as seeds
and the split is redone (:func:`stolen_seeds`; two arms and the previous frame's split only). Where two forearms
cross, one arm's sleeve end can lie over the other hand, whose skin then parts the sleeve from its own hand: that
arm's wrist seeds none of its hand, and since a seed costs nothing the other arm's label takes the whole hand however
much :data:`KEEP_COST` charges (``hands-s2`` seed 2 frames 43–55). New in session 34, off: ``hands-s2``
tuning seeds 0–4, the same frames for both arms, filter seeds 0–4, off → on: it acts on seed 2 only (frames 43–44
mended in every run), ground-truth start F̄^b 0.9181 → 0.9183, ē^p 4.927 → 4.916 px, automatic start 0.9220 → 0.9214,
ē^p 4.541 → 4.610 px (seed 2 0.9139 → 0.9108, the filters' chance after the mended frames), missed hands 9 / 9.
Without the wrist-region condition of :func:`stolen_seeds` it also swapped seed 4's hands back where the new split put a
swapped previous one right (seed 4 worse in all 10 runs). ``benchmarks/history/issue-14-hands.md``."""
STOLEN_OWN = 0.2
"""Share of an arm's previous pixels below which its label in this split counts as having left them
(:data:`STOLEN_RESEED`)."""
STOLEN_OTHER = 0.6
"""Share of an arm's previous pixels above which the other arm's label counts as having taken them
(:data:`STOLEN_RESEED`)."""
STOLEN_MIN_PX = 50
"""Fewest previous pixels (working px, skin in this frame) of an arm for :data:`STOLEN_RESEED` to act."""
STOLEN_ERODE = 2
"""Working px by which an arm's previous pixels are eroded (a square) before they seed it (:data:`STOLEN_RESEED`)."""
MOTION_ITERS = 5
"""Lloyd iterations of the two-means clustering of the labelled skin pixels' flow (started from each arm's median)."""
MOTION_MEDIAN_GATE = True
"""Whether :data:`MOTION_SPLIT` acts only when the two arms' labelled pixels' median flows already lie
:data:`MOTION_SEP` apart (without it, two-means also splits one hand's flow field — a hand turning or moving in
depth — when both hands move alike)."""


@dataclass
class ArmHand:
    """One arm's hand: ``entry`` (x, y) the mean of the arm's border pixels, ``box`` the inclusive box of its skin
    pixels, ``n`` their count (working px)."""

    entry: tuple[float, float]
    box: tuple[int, int, int, int]
    n: int


@nb.njit(cache=True, nogil=True, inline="always")
def _depth_step(z, y, x, yy, xx, step):
    """Whether the move from pixel ``(y, x)`` to its neighbour ``(yy, xx)`` crosses a depth step: both have depth
    (> 0, metres) and they differ by more than ``step``. The geodesic split charges such a move extra."""
    za = z[y, x]
    zb = z[yy, xx]
    return za > 0 and zb > 0 and abs(za - zb) > step


@nb.njit(cache=True, nogil=True, inline="always")
def _edge_cost(grey, y, x, yy, xx, thr, slope):
    """Extra cost (whole working px) of the move from pixel ``(y, x)`` to its neighbour ``(yy, xx)`` across a grey-level
    edge: ``slope`` per grey level by which their difference exceeds ``thr`` (0 with ``slope`` 0)."""
    if slope <= 0:
        return 0
    dg = abs(np.int64(grey[y, x]) - np.int64(grey[yy, xx]))
    return slope * (dg - thr) if dg > thr else 0


@nb.njit(cache=True, nogil=True)
def _geodesic_heap(mask, z, seeds, step, step_cost, prev, prev_cost, grey, edge_thr, edge_slope):
    """:func:`geodesic_labels` with a binary heap (any ``step_cost``, ``prev_cost``)."""
    h, w = mask.shape
    dist = np.full((h, w), 1e18)
    lab = np.zeros((h, w), np.int32)
    heap = [(0.0, 0, 0)]
    heap.pop()
    for y in range(h):
        for x in range(w):
            if seeds[y, x] > 0 and mask[y, x]:
                dist[y, x] = 0.0
                lab[y, x] = seeds[y, x]
                heap.append((0.0, y, x))
    heapq.heapify(heap)
    dys = (1, -1, 0, 0)
    dxs = (0, 0, 1, -1)
    while len(heap):
        d, y, x = heapq.heappop(heap)
        if d > dist[y, x]:
            continue
        for q in range(4):
            yy = y + dys[q]
            xx = x + dxs[q]
            if yy < 0 or xx < 0 or yy >= h or xx >= w or not mask[yy, xx]:
                continue
            c = 1.0 + step_cost if _depth_step(z, y, x, yy, xx, step) else 1.0
            c += _edge_cost(grey, y, x, yy, xx, edge_thr, edge_slope)
            if prev[yy, xx] > 0 and prev[yy, xx] != lab[y, x]:
                c += prev_cost
            nd = d + c
            if nd < dist[yy, xx]:
                dist[yy, xx] = nd
                lab[yy, xx] = lab[y, x]
                heapq.heappush(heap, (nd, yy, xx))
    return lab, dist


@nb.njit(cache=True, nogil=True)
def _geodesic_buckets(mask, z, seeds, step, step_cost, prev, prev_cost, grey, edge_thr, edge_slope):
    """:func:`geodesic_labels` for a whole-number ``step_cost`` with a bucket queue (Dial's algorithm): every distance
    is a whole number, each bucket is complete when its turn comes (steps cost at least 1), and its pixels are taken
    in raster order, the heap's order on equal distances — the same labels and distances, without the heap."""
    h, w = mask.shape
    big = int(step_cost) + 1
    other = int(prev_cost)
    k_ring = big + other + 1 + (edge_slope * max(255 - edge_thr, 0) if edge_slope > 0 else 0)
    dist = np.full((h, w), 1e18)
    lab = np.zeros((h, w), np.int32)
    ring = [np.empty(64, np.int64) for _ in range(k_ring)]
    count = np.zeros(k_ring, np.int64)
    pending = 0
    for y in range(h):
        for x in range(w):
            if seeds[y, x] > 0 and mask[y, x]:
                dist[y, x] = 0.0
                lab[y, x] = seeds[y, x]
                if count[0] == len(ring[0]):
                    grown = np.empty(2 * len(ring[0]), np.int64)
                    grown[: count[0]] = ring[0]
                    ring[0] = grown
                ring[0][count[0]] = y * w + x
                count[0] += 1
                pending += 1
    dys = (1, -1, 0, 0)
    dxs = (0, 0, 1, -1)
    d = 0
    while pending > 0:
        b = d % k_ring
        if count[b] == 0:  # an empty bucket (many, with edge costs): nothing to sort
            d += 1
            continue
        todo = np.sort(ring[b][: count[b]])
        pending -= count[b]
        count[b] = 0
        for p in todo:
            y = p // w
            x = p - y * w
            if d > dist[y, x]:
                continue
            for q in range(4):
                yy = y + dys[q]
                xx = x + dxs[q]
                if yy < 0 or xx < 0 or yy >= h or xx >= w or not mask[yy, xx]:
                    continue
                c = big if _depth_step(z, y, x, yy, xx, step) else 1
                c += _edge_cost(grey, y, x, yy, xx, edge_thr, edge_slope)
                if prev[yy, xx] > 0 and prev[yy, xx] != lab[y, x]:
                    c += other
                nd = d + c
                if nd < dist[yy, xx]:
                    dist[yy, xx] = nd
                    lab[yy, xx] = lab[y, x]
                    t = nd % k_ring
                    if count[t] == len(ring[t]):
                        grown = np.empty(2 * len(ring[t]), np.int64)
                        grown[: count[t]] = ring[t]
                        ring[t] = grown
                    ring[t][count[t]] = yy * w + xx
                    count[t] += 1
                    pending += 1
        d += 1
    return lab, dist


def geodesic_labels(mask: np.ndarray, z: np.ndarray, seeds: np.ndarray, step: float, step_cost: float,
                    prev: np.ndarray | None = None, prev_cost: float = 0.0, grey: np.ndarray | None = None,
                    edge_thr: int = 0, edge_slope: int = 0) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Multi-source geodesic labelling over ``mask`` (uint8 H×W) from ``seeds`` (int32 H×W, 0 = none, k > 0 the
    label; only seeds on the mask count): Dijkstra with 4-neighbour steps of cost 1 plus ``step_cost`` where both
    depths ``z`` (float64 H×W, ≤ 0 unknown) are known and differ by more than ``step``, plus ``edge_slope`` per grey
    level by which the two pixels of ``grey`` (uint8 H×W; None: no edge cost) differ by more than ``edge_thr``
    (whole numbers), plus ``prev_cost`` into a pixel that ``prev`` (int32 H×W, 0 = none; e.g. the last frame's
    labels) gives another label than the one spreading; on equal distances the pixel first in raster order spreads
    its label first. Returns (labels int32, distances float64; 1e18 where not reached)."""
    if prev is None:
        prev = np.zeros(mask.shape, np.int32)
    prev = np.ascontiguousarray(prev, np.int32)
    if grey is None or edge_slope <= 0:
        grey, edge_slope = np.zeros((1, 1), np.uint8), 0
    grey = np.ascontiguousarray(grey, np.uint8)
    thr, slope = int(edge_thr), int(edge_slope)
    if step_cost >= 0 and float(step_cost).is_integer() and prev_cost >= 0 and float(prev_cost).is_integer():
        return _geodesic_buckets(mask, z, seeds, step, step_cost, prev, prev_cost, grey, thr, slope)
    return _geodesic_heap(mask, z, seeds, step, step_cost, prev, float(prev_cost), grey, thr, slope)


def working_depth(depth: np.ndarray, scale: int, shape: tuple[int, int]) -> np.ndarray:
    """Full-resolution depth (m) subsampled every ``scale``-th px to the working ``shape`` (H, W); unknown → 0."""
    return _working_depth(np.asarray(depth), scale, shape[0], shape[1])


@nb.njit(cache=True, nogil=True)
def _working_depth(depth, scale, h, w):
    """float64 [h, w]: ``depth[y·scale, x·scale]`` where finite and > 0, else 0 (also beyond ``depth``'s extent)."""
    out = np.zeros((h, w))
    for y in range(min(h, (depth.shape[0] + scale - 1) // scale)):
        for x in range(min(w, (depth.shape[1] + scale - 1) // scale)):
            v = np.float64(depth[y * scale, x * scale])
            if np.isfinite(v) and v > 0:
                out[y, x] = v
    return out


@nb.njit(cache=True, nogil=True)
def _foreground_raw(z, background, gap):
    """uint8 mask of the pixels with background depth that are nearer by ``gap`` or have no depth (not opened)."""
    h, w = z.shape
    fg = np.zeros((h, w), np.uint8)
    for y in range(h):
        for x in range(w):
            b = background[y, x]
            if b > 0:
                zz = z[y, x]
                if zz <= 0 or zz < b - gap:
                    fg[y, x] = 1
    return fg


def foreground(z: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Bool mask of the pixels nearer than ``background`` by FG_GAP, or without depth where the background has it."""
    fg = _foreground_raw(np.ascontiguousarray(z, np.float64), np.ascontiguousarray(background, np.float64), FG_GAP)
    return cv2.morphologyEx(fg, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)


@nb.njit(cache=True, nogil=True)
def _one_border_run(ys, xs, h, w, b, gap, min_run):
    """Whether the border pixels (``ys``, ``xs``, image rows and columns within ``b`` px of the border) form exactly
    one run of at least ``min_run`` pixels along the image border: sorted by their clockwise perimeter coordinate
    (from the top-left corner), split where consecutive ones lie more than ``gap`` apart, the last and first run
    joined when they meet through the top-left corner."""
    n = len(ys)
    p = np.empty(n)
    for i in range(n):
        y, x = ys[i], xs[i]
        if y < b:
            p[i] = x
        elif x >= w - b:
            p[i] = w + y
        elif y >= h - b:
            p[i] = w + h + (w - x)
        else:
            p[i] = 2 * w + h + (h - y)
    p = np.sort(p)
    lens = []
    cur = 1
    for i in range(1, n):
        if p[i] - p[i - 1] > gap:
            lens.append(cur)
            cur = 1
        else:
            cur += 1
    lens.append(cur)
    if len(lens) > 1 and p[0] + 2 * (w + h) - p[n - 1] <= gap:  # a run through the top-left corner
        lens[0] += lens[-1]
        lens.pop()
    k = 0
    for ln in lens:
        if ln >= min_run:
            k += 1
    return k == 1


@nb.njit(cache=True, nogil=True)
def _arm_seeds(sk, near, sleeve, b, min_area, gap, min_run, wrist_far):
    """The arms of one frame and their hands' seed pixels (steps 2–3 of the module docstring): the 8-connected
    components of ``sleeve`` (uint8) that reach within ``b`` px of the image border, of at least ``min_area`` px,
    whose border pixels form one run; each one's wrist (its pixels at least ``wrist_far`` of the farthest
    straight-line distance from the entry point where ``near``, the skin ``sk`` dilated by 2 px, is set) and the skin
    pixels within 2 px of the wrist as seeds. Components in the order of their first 2 × 2 block in raster order (as
    OpenCV's block-based labelling numbers them). Returns (seeds int32 H×W, 0 = none, k + 1 = the k-th arm; entries
    float64 [n, 2] (x, y); the pixels of all border components, columns and rows int32; the [start, end) spans in
    them of the components of at least ``min_area`` px whose border pixels do not form one run, int64 [m, 2])."""
    h, w = sleeve.shape
    w2 = w + 2
    pad = np.zeros((h + 2) * w2, np.uint8)  # the sleeve with a 1 px frame of zeros, flat; 255 = visited
    for y in range(h):
        for x in range(w):
            pad[(y + 1) * w2 + x + 1] = sleeve[y, x]
    offs = np.array([-w2 - 1, -w2, -w2 + 1, -1, 1, w2 - 1, w2, w2 + 1])
    oy = np.empty(h * w, np.int32)  # the components' pixels, one after the other
    ox = np.empty(h * w, np.int32)
    queue = np.empty(h * w, np.int64)
    starts = [0]
    firsts = []
    top = 0
    for y in range(h):
        for x in range(w):
            p0 = (y + 1) * w2 + x + 1
            if not (y < b or y >= h - b or x < b or x >= w - b) or pad[p0] != 1:
                continue
            first = h * w
            pad[p0] = 255
            queue[top] = p0
            head = top
            top += 1
            while head < top:
                q = queue[head]
                head += 1
                for o in offs:
                    if pad[q + o] == 1:
                        pad[q + o] = 255
                        queue[top] = q + o
                        top += 1
            for i in range(starts[-1], top):
                qy = queue[i] // w2
                oy[i] = qy - 1
                ox[i] = queue[i] - qy * w2 - 1
                first = min(first, (oy[i] // 2) * w + ox[i] // 2)
            starts.append(top)
            firsts.append(first)
    seeds = np.zeros((h, w), np.int32)
    entries = np.zeros((len(firsts), 2))
    n_arms = 0
    multi = [0]  # the components whose border pixels are not one run (an empty list of ints, as numba types it)
    multi.pop()
    dist = np.empty(h * w)
    for c in np.argsort(np.array(firsts)):
        s0 = starts[c]
        s1 = starts[c + 1]
        if s1 - s0 < min_area:
            continue
        x0 = w
        y0 = h
        nb_ = 0
        for i in range(s0, s1):
            x0 = min(x0, ox[i])
            y0 = min(y0, oy[i])
            if oy[i] < b or oy[i] >= h - b or ox[i] < b or ox[i] >= w - b:
                nb_ += 1
        ys = np.empty(nb_, np.int64)
        xs = np.empty(nb_, np.int64)
        k = 0
        for i in range(s0, s1):
            if oy[i] < b or oy[i] >= h - b or ox[i] < b or ox[i] >= w - b:
                ys[k] = oy[i]
                xs[k] = ox[i]
                k += 1
        if not _one_border_run(ys, xs, h, w, b, gap, min_run):
            multi.append(c)  # no run or several (crossing arms: _crossed_seeds)
            continue
        ex = float(np.sum(xs - x0)) / nb_
        ey = float(np.sum(ys - y0)) / nb_
        dmax = 0.0
        for i in range(s0, s1):
            dist[i] = math.hypot((ox[i] - x0) - ex, (oy[i] - y0) - ey)
            dmax = max(dmax, dist[i])
        thr = wrist_far * dmax
        label = n_arms + 1
        has_wrist = False  # a wrist pixel has skin within 2 px: that skin seeds the hand
        for i in range(s0, s1):
            if dist[i] < thr or near[oy[i], ox[i]] == 0:
                continue
            has_wrist = True
            qy = oy[i]
            qx = ox[i]
            for yy in range(max(qy - 2, 0), min(qy + 3, h)):
                for xx in range(max(qx - 2, 0), min(qx + 3, w)):
                    if sk[yy, xx] != 0 and seeds[yy, xx] == 0:
                        seeds[yy, xx] = label
        if not has_wrist:
            continue
        entries[n_arms, 0] = ex + x0
        entries[n_arms, 1] = ey + y0
        n_arms += 1
    spans = np.empty((len(multi), 2), np.int64)
    for i in range(len(multi)):
        spans[i, 0] = starts[multi[i]]
        spans[i, 1] = starts[multi[i] + 1]
    return seeds, entries[:n_arms], ox[:top], oy[:top], spans


@nb.njit(cache=True, nogil=True)
def _label_boxes(labels, n):
    """Inclusive boxes [n, 4] (u0, v0, u1, v1) and pixel counts [n] of labels 1..n in ``labels``."""
    h, w = labels.shape
    boxes = np.empty((n, 4), np.int64)
    boxes[:, 0] = w
    boxes[:, 1] = h
    boxes[:, 2] = -1
    boxes[:, 3] = -1
    counts = np.zeros(n, np.int64)
    for y in range(h):
        for x in range(w):
            k = labels[y, x] - 1
            if 0 <= k < n:
                counts[k] += 1
                boxes[k, 0] = min(boxes[k, 0], x)
                boxes[k, 1] = min(boxes[k, 1], y)
                boxes[k, 2] = max(boxes[k, 2], x)
                boxes[k, 3] = max(boxes[k, 3], y)
    return boxes, counts


@nb.njit(cache=True, nogil=True)
def _rim_boxes(labels, skin, boxes, r):
    """Grow the inclusive boxes [n, 4] of labels 1..n (in place) over the unlabelled pixels of ``skin`` (uint8, the
    unopened colour mask) that have a pixel with that label within ``r`` px (Chebyshev distance)."""
    h, w = labels.shape
    n = boxes.shape[0]
    for y in range(h):
        for x in range(w):
            if skin[y, x] == 0 or labels[y, x] != 0:
                continue
            for yy in range(max(y - r, 0), min(y + r + 1, h)):
                for xx in range(max(x - r, 0), min(x + r + 1, w)):
                    k = labels[yy, xx] - 1
                    if 0 <= k < n:
                        boxes[k, 0] = min(boxes[k, 0], x)
                        boxes[k, 1] = min(boxes[k, 1], y)
                        boxes[k, 2] = max(boxes[k, 2], x)
                        boxes[k, 3] = max(boxes[k, 3], y)
    return boxes


@dataclass
class ArmSplit:
    """One frame's split of the skin between the arms: ``labels`` (int32 working H×W, k + 1 = the k-th arm, 0 = none)
    and ``entries`` (float64 [n, 2], each arm's entry point (x, y), working px)."""

    labels: np.ndarray
    entries: np.ndarray


def arm_hands(skin: np.ndarray, z: np.ndarray, background: np.ndarray) -> list[ArmHand]:
    """The hands at the ends of the arms of one frame (module docstring). ``skin``: the colour mask (uint8 0/1,
    working H×W); ``z``, ``background``: this frame's and the first frame's depth at the working resolution (m, 0 =
    unknown)."""
    return arm_split(skin, z, background)[0]


def behind_seeds(seeds: np.ndarray, sk: np.ndarray, sleeve: np.ndarray, z: np.ndarray, n_arms: int) -> np.ndarray:
    """``seeds`` (int32 H×W, arm k's wrist seeds = k) without the seeds whose skin does not lie :data:`BEHIND_GAP`
    behind the sleeve beside them (:data:`SEED_BEHIND`): per seed, the medians of the known depths (``z``, m, ≤ 0
    unknown) of the skin (``sk``) and of the sleeve (``sleeve``) pixels within :data:`BEHIND_R` px; an arm none of whose
    seeds would be left keeps them all. A new array; ``seeds`` is not changed."""
    return _behind_seeds(np.ascontiguousarray(seeds, np.int32), np.ascontiguousarray(sk, np.uint8),
                         np.ascontiguousarray(sleeve, np.uint8), np.ascontiguousarray(z, np.float64), n_arms,
                         float(BEHIND_GAP), int(BEHIND_R))  # fmt: skip


@nb.njit(cache=True, nogil=True)
def _behind_seeds(seeds, sk, sleeve, z, n_arms, gap, r):
    """:func:`behind_seeds`' work: the seeds not behind their sleeve marked, then dropped (:func:`_drop_marked`)."""
    h, w = seeds.shape
    gone = np.zeros((h, w), np.uint8)
    side = 2 * r + 1
    a = np.empty(side * side)
    b = np.empty(side * side)
    for y in range(h):
        for x in range(w):
            s = seeds[y, x]
            if s <= 0 or s > n_arms:
                continue
            na = 0
            nb_ = 0
            for yy in range(max(y - r, 0), min(y + r + 1, h)):
                for xx in range(max(x - r, 0), min(x + r + 1, w)):
                    d = z[yy, xx]
                    if d <= 0:
                        continue
                    if sk[yy, xx] != 0:
                        a[na] = d
                        na += 1
                    elif sleeve[yy, xx] != 0:
                        b[nb_] = d
                        nb_ += 1
            if na > 0 and nb_ > 0 and np.median(a[:na]) - np.median(b[:nb_]) < gap:
                gone[y, x] = 1
    return _drop_marked(seeds, gone, n_arms)


def stolen_seeds(labels: np.ndarray, carried: np.ndarray, sk: np.ndarray, seeds: np.ndarray) -> np.ndarray | None:
    """Two arms' wrist seeds (``seeds``, int32 H×W, 1 and 2) plus, for an arm whose hand the other arm's label took
    (:data:`STOLEN_RESEED`), its previous pixels as seeds; None when neither arm's was taken. An arm's hand counts as
    taken when of its previous pixels (``carried``, the previous split renumbered to these arms, that are skin in the
    opened mask ``sk``; at least :data:`STOLEN_MIN_PX`) less than :data:`STOLEN_OWN` got its label in this split
    (``labels``) and more than :data:`STOLEN_OTHER` the other arm's; its seeds are then those pixels eroded by
    :data:`STOLEN_ERODE` px (a square; the hand moves a few px a frame) where no wrist seeds lie. Not when its wrist
    seeds lie in 8-connected skin regions of ``sk`` that hold :data:`STOLEN_OWN` of those pixels or more: its wrist
    then reaches its previous hand's region, and the new split may be putting a wrong previous one right."""
    out = None
    comps = None
    for k in (1, 2):
        mine = (carried == k) & (sk > 0)
        n = int(np.count_nonzero(mine))
        if n < STOLEN_MIN_PX:
            continue
        kept = int(np.count_nonzero(mine & (labels == k)))
        taken = int(np.count_nonzero(mine & (labels == 3 - k)))
        if kept >= STOLEN_OWN * n or taken <= STOLEN_OTHER * n:
            continue
        if comps is None:
            comps = cv2.connectedComponents(np.ascontiguousarray(sk, np.uint8), connectivity=8)[1]
        if np.count_nonzero(mine & np.isin(comps, comps[seeds == k])) >= STOLEN_OWN * n:
            continue  # its wrist reaches the skin region of its previous hand: a correction of the split, not a loss
        side = 2 * STOLEN_ERODE + 1
        core = (cv2.erode(mine.astype(np.uint8), np.ones((side, side), np.uint8)) > 0) & (seeds == 0)
        if core.any():
            out = seeds.copy() if out is None else out
            out[core] = k
    return out


def vetoed_seeds(seeds: np.ndarray, carried: np.ndarray, n_arms: int) -> np.ndarray:
    """``seeds`` (int32 H×W, arm k's wrist seeds = k) without the pixels that ``carried`` (the previous split's labels
    renumbered to these arms, :func:`carried_labels`) gave another arm; an arm none of whose seeds would be left keeps
    them all (:data:`SEED_VETO`). A new array; ``seeds`` is not changed."""
    return _vetoed_seeds(np.ascontiguousarray(seeds, np.int32), np.ascontiguousarray(carried, np.int32), n_arms)


@nb.njit(cache=True, nogil=True)
def _vetoed_seeds(seeds, carried, n_arms):
    """:func:`vetoed_seeds`' work: the seeds in another arm's previous pixels marked, then dropped
    (:func:`_drop_marked`)."""
    h, w = seeds.shape
    gone = np.zeros((h, w), np.uint8)
    for y in range(h):
        for x in range(w):
            s = seeds[y, x]
            c = carried[y, x]
            if 0 < s <= n_arms and c > 0 and c != s:
                gone[y, x] = 1
    return _drop_marked(seeds, gone, n_arms)


@nb.njit(cache=True, nogil=True)
def _drop_marked(seeds, gone, n_arms):
    """A copy of ``seeds`` (arm k's wrist seeds = k, 1 ≤ k ≤ ``n_arms``) without the seeds ``gone`` marks, except for
    an arm all of whose seeds are marked: it keeps them all."""
    h, w = seeds.shape
    mine = np.zeros(n_arms + 1, np.int64)
    drop = np.zeros(n_arms + 1, np.int64)
    for y in range(h):
        for x in range(w):
            s = seeds[y, x]
            if 0 < s <= n_arms:
                mine[s] += 1
                drop[s] += gone[y, x] != 0
    out = seeds.copy()
    for y in range(h):
        for x in range(w):
            s = seeds[y, x]
            if 0 < s <= n_arms and gone[y, x] and 0 < drop[s] < mine[s]:
                out[y, x] = 0
    return out


def carried_labels(prev: ArmSplit, entries: np.ndarray) -> np.ndarray:
    """``prev``'s labels renumbered to this frame's arms (``entries`` [n, 2], working px): each previous arm takes the
    label of the arm whose entry lies nearest its own within KEEP_ENTRY_NEAR (nearest pairs first, one to one); a
    previous arm without one is dropped (0)."""
    pairs = sorted((float(np.hypot(*(e - f))), j, k) for j, f in enumerate(prev.entries) for k, e in enumerate(entries))
    remap = np.zeros(len(prev.entries) + 1, np.int32)
    used_j: set[int] = set()
    used_k: set[int] = set()
    for dd, j, k in pairs:
        if dd <= KEEP_ENTRY_NEAR and j not in used_j and k not in used_k:
            used_j.add(j)
            used_k.add(k)
            remap[j + 1] = k + 1
    if np.array_equal(remap, np.arange(len(remap))):
        return prev.labels  # the same arms in the same order (the usual case)
    return remap[np.clip(prev.labels, 0, len(prev.entries))]


@nb.njit(cache=True, nogil=True)
def _motion_prior(labels, f, x0, y0, min_px, sep, margin, iters, median_gate):
    """:func:`motion_prior`'s work: (int32 H×W prior, whether it acts)."""
    h, w = labels.shape
    out = np.zeros((h, w), np.int32)
    x1 = min(x0 + f.shape[1], w)
    y1 = min(y0 + f.shape[0], h)
    n = 0
    for y in range(y0, y1):
        for x in range(x0, x1):
            if labels[y, x] > 0:
                n += 1
    if n == 0:
        return out, False
    v = np.empty((n, 2))
    lv = np.empty(n, np.int32)
    i = 0
    for y in range(y0, y1):
        for x in range(x0, x1):
            if labels[y, x] > 0:
                v[i, 0] = f[y - y0, x - x0, 0]
                v[i, 1] = f[y - y0, x - x0, 1]
                lv[i] = labels[y, x]
                i += 1
    a = lv == 1
    b = lv == 2
    if a.sum() < min_px or b.sum() < min_px:
        return out, False
    c = np.empty((2, 2))
    c[0, 0] = np.median(v[a, 0])
    c[0, 1] = np.median(v[a, 1])
    c[1, 0] = np.median(v[b, 0])
    c[1, 1] = np.median(v[b, 1])
    if median_gate and (c[1, 0] - c[0, 0]) ** 2 + (c[1, 1] - c[0, 1]) ** 2 < sep * sep:
        return out, False
    for _ in range(iters):
        s = np.zeros((2, 2))
        k = np.zeros(2)
        for j in range(n):
            d0 = (v[j, 0] - c[0, 0]) ** 2 + (v[j, 1] - c[0, 1]) ** 2
            d1 = (v[j, 0] - c[1, 0]) ** 2 + (v[j, 1] - c[1, 1]) ** 2
            q = 1 if d1 < d0 else 0
            s[q, 0] += v[j, 0]
            s[q, 1] += v[j, 1]
            k[q] += 1
        if k[0] == 0 or k[1] == 0:
            return out, False
        for q in range(2):
            c[q, 0] = s[q, 0] / k[q]
            c[q, 1] = s[q, 1] / k[q]
    dx = c[1, 0] - c[0, 0]
    dy = c[1, 1] - c[0, 1]
    sep2 = dx * dx + dy * dy
    if sep2 < sep * sep:
        return out, False
    for y in range(y0, y1):
        for x in range(x0, x1):
            if labels[y, x] > 0:
                t = ((f[y - y0, x - x0, 0] - c[0, 0]) * dx + (f[y - y0, x - x0, 1] - c[0, 1]) * dy) / sep2
                if t < 0.5 - margin:
                    out[y, x] = 1
                elif t > 0.5 + margin:
                    out[y, x] = 2
    return out, True


def motion_prior(labels: np.ndarray, flow: tuple[np.ndarray, int, int]) -> np.ndarray | None:
    """Each skin pixel's hand by its optical flow, for two arms (:data:`MOTION_SPLIT`): ``labels`` the split (int32
    working H×W, 1 and 2 the arms), ``flow`` (f, x0, y0): a flow [h, w, 2] (working px per frame) on the region whose
    top-left working px is (x0, y0). Unless the two labels' median flows lie less than :data:`MOTION_SEP` apart
    (:data:`MOTION_MEDIAN_GATE`), the flows of the labelled pixels in the region are clustered by two-means started
    from those medians (:data:`MOTION_ITERS` iterations); when the two centres lie at least :data:`MOTION_SEP` apart, a
    pixel whose flow projects onto the line between them below 0.5 − :data:`MOTION_MARGIN` (towards label 1's centre)
    gets 1, above 0.5 + :data:`MOTION_MARGIN` 2, others 0. Returns int32 H×W (0 outside the region), or None (fewer
    than MIN_HAND_PX pixels of a label in the region, or motions too alike)."""
    f, x0, y0 = flow
    out, ok = _motion_prior(np.ascontiguousarray(labels, np.int32), np.ascontiguousarray(f, np.float32), int(x0),
                            int(y0), MIN_HAND_PX, float(MOTION_SEP), float(MOTION_MARGIN), int(MOTION_ITERS),
                            bool(MOTION_MEDIAN_GATE))  # fmt: skip
    return out if ok else None


def arm_split(skin: np.ndarray, z: np.ndarray, background: np.ndarray, prev: ArmSplit | None = None,
              flow: tuple[np.ndarray, int, int] | None = None,
              grey: np.ndarray | None = None) -> tuple[list[ArmHand], ArmSplit | None]:  # fmt: skip
    """:func:`arm_hands` and the split behind it (None when no arm is found). With ``prev`` (the previous frame's
    split) and KEEP_COST > 0, a label spreading into a skin pixel the previous split gave another arm pays KEEP_COST
    (the arms are matched by their entry points, :func:`carried_labels`). With ``flow`` (f [h, w, 2] working px per
    frame, x0, y0: the working px of its top-left pixel; the backward flow of this frame is fine, only differences
    count) and :data:`MOTION_SPLIT`, two arms' split is redone with :func:`motion_prior`. With ``grey`` (uint8, the
    working frame's grey levels) and :data:`EDGE_SPLIT`, crossing a grey-level edge costs :data:`EDGE_SLOPE` per level
    above :data:`EDGE_THR`."""
    h, w = skin.shape
    sk = cv2.morphologyEx(np.ascontiguousarray(skin, np.uint8), cv2.MORPH_OPEN,
                          cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))  # fmt: skip
    if not sk.any():
        return [], None
    z = np.ascontiguousarray(z, np.float64)
    background = np.ascontiguousarray(background, np.float64)
    fg = cv2.morphologyEx(_foreground_raw(z, background, FG_GAP), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    if cv2.countNonZero(fg) > MAX_FG_FRAC * max(np.count_nonzero(background > 0), 1):
        return [], None  # the background frame no longer fits (the camera moved, or a hand was in the first frame)
    sleeve = cv2.bitwise_and(fg, 1 - cv2.dilate(sk, np.ones((3, 3), np.uint8)))
    sleeve = cv2.morphologyEx(sleeve, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    near = cv2.dilate(sk, np.ones((5, 5), np.uint8))
    seeds, entries, ox, oy, spans = _arm_seeds(sk, near, sleeve, BORDER_PX, MIN_ARM_FRAC * h * w, RUN_GAP, MIN_RUN,
                                               WRIST_FAR)  # fmt: skip
    if SEED_BEHIND and len(entries):
        seeds = behind_seeds(seeds, sk, sleeve, z, len(entries))
    if CROSS_SPLIT and len(entries) < 2 and len(spans):
        seeds, entries = _crossed_seeds(sk, near, [(ox[a:b], oy[a:b]) for a, b in spans], seeds, entries)
    if not len(entries):
        return [], None
    zg = z
    if HOLE_STEP:
        hole = (z <= 0).astype(np.uint8)
        if HOLE_GROW:
            hole = cv2.dilate(hole, np.ones((2 * HOLE_GROW + 1, 2 * HOLE_GROW + 1), np.uint8))
        zg = np.where((hole > 0) & (sk > 0), HOLE_DEPTH, z)
    carried = carried_labels(prev, entries) if prev is not None and KEEP_COST > 0 else None
    if SEED_VETO and prev is not None:
        seeds = vetoed_seeds(seeds, carried if carried is not None else carried_labels(prev, entries), len(entries))
    edges = {"grey": grey, "edge_thr": EDGE_THR, "edge_slope": EDGE_SLOPE} if EDGE_SPLIT and grey is not None else {}

    def split_labels(seeds: np.ndarray) -> np.ndarray:
        labels, _ = geodesic_labels(sk, zg, seeds, DEPTH_STEP, DEPTH_STEP_COST, carried, KEEP_COST, **edges)
        if MOTION_SPLIT and flow is not None and len(entries) == 2:
            moved = motion_prior(labels, flow)
            if moved is not None:
                if carried is not None:  # where the flow does not decide, the previous split's labels still count
                    moved = np.where(moved > 0, moved, carried).astype(np.int32)
                labels, _ = geodesic_labels(sk, zg, seeds, DEPTH_STEP, DEPTH_STEP_COST, moved, MOTION_COST, **edges)
        return labels

    labels = split_labels(seeds)
    if STOLEN_RESEED and carried is not None and len(entries) == 2:
        reseeded = stolen_seeds(labels, carried, sk, seeds)
        if reseeded is not None:
            labels = split_labels(reseeded)
    boxes, counts = _label_boxes(labels, len(entries))
    if BOX_RIM:
        _rim_boxes(labels, np.ascontiguousarray(skin, np.uint8), boxes, RIM_PX)
    hands = [ArmHand((float(e[0]), float(e[1])), (int(b[0]), int(b[1]), int(b[2]), int(b[3])), int(c))
             for e, b, c in zip(entries, boxes, counts, strict=True) if c >= MIN_HAND_PX]  # fmt: skip
    return hands, ArmSplit(labels, np.asarray(entries, np.float64))


def _border_runs(ys: np.ndarray, xs: np.ndarray, h: int, w: int) -> list[np.ndarray]:
    """The runs (index arrays into ``ys``, ``xs``) of border pixels along the image border, as
    :func:`_one_border_run` finds them (at least MIN_RUN pixels each)."""
    b = BORDER_PX
    p = np.where(ys < b, xs, np.where(xs >= w - b, w + ys,
                                      np.where(ys >= h - b, w + h + (w - xs), 2 * w + h + (h - ys))))  # fmt: skip
    order = np.argsort(p, kind="stable")
    ps = p[order].astype(np.float64)
    cuts = np.nonzero(np.diff(ps) > RUN_GAP)[0] + 1
    runs = np.split(order, cuts)
    if len(runs) > 1 and ps[0] + 2 * (w + h) - ps[-1] <= RUN_GAP:
        runs[0] = np.concatenate([runs[-1], runs[0]])
        runs.pop()
    return [r for r in runs if len(r) >= MIN_RUN]


@nb.njit(cache=True, nogil=True)
def _tube_fit(xs, ys, ents, r0, r1):
    """Per run k of a crossing component (pixels ``xs``, ``ys``; entry points ``ents`` [2, 2] (x, y)): each pixel's
    straight-line distance ``d[k]`` from the entry, the pixels ``sel[k]`` that give the tube's direction (``r0``–``r1``
    px from its entry, nearer it than the other), and each pixel's distance ``perp[k]`` from the axis through the
    entry and those pixels' centroid (behind the entry: ``d[k]``). Returns (d, perp, sel, counts of sel)."""
    n = len(xs)
    d = np.empty((2, n))
    perp = np.empty((2, n))
    sel = np.zeros((2, n), np.bool_)
    cnt = np.zeros(2, np.int64)
    for i in range(n):
        for k in range(2):
            dx = xs[i] - ents[k, 0]
            dy = ys[i] - ents[k, 1]
            d[k, i] = math.sqrt(dx * dx + dy * dy)
    for k in range(2):
        sx = 0.0
        sy = 0.0
        for i in range(n):
            if r0 <= d[k, i] <= r1 and d[k, i] < d[1 - k, i]:
                sel[k, i] = True
                cnt[k] += 1
                sx += xs[i]
                sy += ys[i]
        ax = sx / max(cnt[k], 1) - ents[k, 0]
        ay = sy / max(cnt[k], 1) - ents[k, 1]
        norm = max(math.hypot(ax, ay), 1e-9)
        ax /= norm
        ay /= norm
        for i in range(n):
            rx = xs[i] - ents[k, 0]
            ry = ys[i] - ents[k, 1]
            perp[k, i] = d[k, i] if rx * ax + ry * ay < 0 else abs(rx * ay - ry * ax)
    return d, perp, sel, cnt


@nb.njit(cache=True, nogil=True)
def _tube_wrists(xs, ys, d, perp, reach, near, wrist_far, min_px):
    """Each tube's wrist pixels (bool [2, n]) of a crossing component: a pixel within ``reach[k]`` of tube k's axis
    belongs to it (to the nearer axis if within both); the tube's pixels at least ``wrist_far`` of its farthest
    distance ``d[k]`` from its entry with skin within 2 px (``near``) are its wrist. A tube of fewer than ``min_px``
    pixels has none."""
    n = len(xs)
    far = np.zeros((2, n), np.bool_)
    member = np.empty(n, np.bool_)
    for k in range(2):
        o = 1 - k
        cnt = 0
        dmax = 0.0
        for i in range(n):
            member[i] = perp[k, i] <= reach[k] and (perp[o, i] > reach[o] or perp[k, i] < perp[o, i])
            if member[i]:
                cnt += 1
                dmax = max(dmax, d[k, i])
        if cnt < min_px:
            continue
        thr = wrist_far * dmax
        for i in range(n):
            far[k, i] = member[i] and d[k, i] >= thr and near[ys[i], xs[i]] > 0
    return far


def _crossed_seeds(sk: np.ndarray, near: np.ndarray, comps: list[tuple[np.ndarray, np.ndarray]], seeds: np.ndarray,
                   entries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Two forearms that cross form one sleeve component that meets the image border in two runs (``CROSS_SPLIT``).
    Each run's arm is a tube from its entry point (the mean of the run's pixels) along the direction to the centroid
    of the component's pixels TUBE_R0–TUBE_R1 working px from that point and nearer it than the other run's (the
    forearm before the crossing), of radius the 90th percentile of those pixels' distances from the axis (pixels
    behind the entry: their distance from it). A component pixel within TUBE_GROW radii (+ 1 px) of a tube's axis
    belongs to that tube, to the nearer axis if within both: the crossing is shared along both axes and each tube
    runs on past it to its own far end, also where the lower arm's visible sleeve ends at the upper one. Each tube
    then seeds its hand as an arm does: the skin within 2 px of its pixels at least WRIST_FAR of its farthest
    distance from the entry that have skin within 2 px (``near``). Both are dropped when their seeds lie in one
    8-connected skin region (``CROSS_TOUCH_DROP``: touching hands, the tubes do not tell which hand is whose).
    ``comps``: the (columns, rows) of the border components whose border pixels do not form one run; ``seeds``
    (int32 H×W, changed in place) and ``entries`` ([n, 2] (x, y)) as :func:`_arm_seeds` returns them; returns them
    with these arms appended."""
    h, w = sk.shape
    b = BORDER_PX
    out = list(entries)
    skin_lab = None
    for xs, ys in comps:
        on_b = (ys < b) | (ys >= h - b) | (xs < b) | (xs >= w - b)
        bys, bxs = ys[on_b], xs[on_b]
        runs = _border_runs(bys, bxs, h, w)
        if len(runs) != 2:
            continue
        ents = np.array([[bxs[r].mean(), bys[r].mean()] for r in runs])
        d, perp, sel, cnt = _tube_fit(xs, ys, ents, TUBE_R0, TUBE_R1)
        if cnt.min() < MIN_HAND_PX:
            continue
        reach = np.array([TUBE_GROW * order_stats.quantile(perp[k][sel[k]], 0.9) + 1.0 for k in range(2)])
        far = _tube_wrists(xs, ys, d, perp, reach, near, WRIST_FAR, MIN_HAND_PX)
        found: list[np.ndarray | None] = []
        for k in range(2):
            if not far[k].any():
                found.append(None)
                continue
            wrist = np.zeros((h, w), np.uint8)
            wrist[ys[far[k]], xs[far[k]]] = 1
            found.append((cv2.dilate(wrist, np.ones((5, 5), np.uint8)) > 0) & (sk > 0))
        if CROSS_TOUCH_DROP and found[0] is not None and found[1] is not None:
            if skin_lab is None:
                skin_lab = cv2.connectedComponents(sk, connectivity=8)[1]
            if set(np.unique(skin_lab[found[0]]).tolist()) & set(np.unique(skin_lab[found[1]]).tolist()):
                continue  # both wrists reach one skin region: the tubes do not tell which hand is whose
        for k in range(2):
            if found[k] is not None:
                seeds[found[k] & (seeds == 0)] = len(out) + 1
                out.append(ents[k])
    return seeds, np.asarray(out, np.float64).reshape(-1, 2)
