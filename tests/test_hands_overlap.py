"""Two hands through an overlap (tracker/hands): the mutual exclusion of two tracks' particles
(:mod:`tracker.hands.exclusion`) and the group box of two stacked hands (:mod:`tracker.hands.group_box`). Synthetic
frames at scale 1 (working px = image px)."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.hands.exclusion import exclusion_factors
from tracker.hands.metrics import dice
from tracker.hands.particle_filter import HandParticleFilter, PFParams
from tracker.hands.tracker import HandTracker, HandTrackerConfig

SKIN = (215, 160, 130)  # RGB of a light skin tone (inside the shipped skin model's region)
TABLE = (120, 130, 140)
BOX_A = [60, 110, 90, 150]
BOX_B = [200, 110, 230, 150]


def _table() -> np.ndarray:
    return np.zeros((240, 320, 3), np.uint8) + np.uint8(TABLE)


def _two_hands() -> np.ndarray:
    """Two skin squares (hand A left, hand B right, end-exclusive boxes BOX_A, BOX_B) with sleeves below them."""
    img = _table()
    for (u0, v0, u1, v1), sleeve in ((BOX_A, (20, 120, 40)), (BOX_B, (40, 40, 160))):
        img[v1:240, u0 + 4 : u1 - 4] = sleeve
        img[v0:v1, u0:u1] = SKIN
    return img


def _stacked() -> np.ndarray:
    """One skin region (end-exclusive [120, 100, 165, 150]): hand B lying on hand A, both sleeves below it."""
    img = _table()
    img[150:240, 124:140] = (20, 120, 40)
    img[150:240, 146:161] = (40, 40, 160)
    img[100:150, 120:165] = SKIN
    return img


def test_exclusion_factor_penalises_only_boxes_that_coincide_with_another_track():
    others = np.array([[100.0, 100.0, 139.0, 139.0]])  # inclusive 40 × 40 box
    parts = np.array([[119.5, 119.5, 39.0, 39.0],  # the same box: F = 1
                      [129.5, 119.5, 39.0, 39.0],  # shifted by a quarter: F = 0.75
                      [149.5, 119.5, 39.0, 39.0],  # half overlapping: F = 0.25
                      [300.0, 300.0, 39.0, 39.0]])  # fmt: skip
    psi = exclusion_factors(parts, others, 0.5, 10.0)
    assert psi[0] == pytest.approx(np.exp(-5.0))
    assert psi[1] == pytest.approx(np.exp(-2.5))
    assert psi[2] == 1.0 and psi[3] == 1.0
    assert np.all(exclusion_factors(parts, np.zeros((0, 4)), 0.5, 10.0) == 1.0)


def test_a_particle_filter_avoids_the_other_tracks_box():
    """Particles split over two equal hands: told to avoid hand A's box the estimate is on hand B and vice versa
    (without the exclusion one filter run cannot give both)."""
    tr = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=0))
    tr.process(_table())
    tr.process(_two_hands())
    tr.start_track(BOX_A)
    tr.start_track(BOX_B)  # the features' ROI holds both hands
    tr.process(_two_hands())
    feats = tr.last_features
    a = tr.from_full_box(BOX_A)
    b = tr.from_full_box(BOX_B)
    inc_a = np.array([[BOX_A[0], BOX_A[1], BOX_A[2] - 1, BOX_A[3] - 1]], float)
    inc_b = np.array([[BOX_B[0], BOX_B[1], BOX_B[2] - 1, BOX_B[3] - 1]], float)
    roi = feats.roi
    assert roi[0] <= BOX_A[0] and roi[2] >= BOX_B[2]  # both hands inside the features' ROI
    ests = []
    for avoid in (inc_a, inc_b):
        pf = HandParticleFilter(a, PFParams(n_particles=10), rng=np.random.default_rng(0))
        pf.particles[5:] = b
        pf.step(feats, (320, 240), avoid)
        ests.append(pf.estimate)
    assert dice(_box(ests[0]), BOX_B) > 0.8
    assert dice(_box(ests[1]), BOX_A) > 0.8


def _box(state: np.ndarray) -> list[float]:
    x, y, w, h = state[:4]
    return [x - w / 2, y - h / 2, x + w / 2 + 1, y + h / 2 + 1]


@pytest.mark.parametrize("group", [True, False])
def test_two_stacked_hands_report_the_box_of_their_shared_skin(group: bool):
    tr = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=0, group_box=group))
    tr.process(_table())
    tr.process(_stacked())
    a = tr.start_track([120, 100, 142, 150])  # the two tracks on the two halves of the one skin region
    b = tr.start_track([142, 100, 165, 150])
    for t in tr.tracks:
        t.area_apart = 31.0 * 41.0  # one-hand box area learnt while apart (a 30 × 40 px palm)
    ests = {e.id: e.box for e in tr.process(_stacked())}
    assert set(ests) == {a, b}
    blob = [120, 100, 165, 150]
    if group:
        assert ests[a] == ests[b] and dice(ests[a], blob) > 0.95
        assert tr.tracks[0].filt.estimate[2] < 40  # the filters keep their own (half) boxes
    else:
        assert ests[a] != ests[b]
    tr2 = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=0, group_box=group))
    tr2.process(_table())
    tr2.process(_stacked())
    tr2.start_track([120, 100, 142, 150])
    tr2.start_track([142, 100, 165, 150])
    for t in tr2.tracks:
        t.area_apart = 15.0 * 20.0  # small hands: the region is two hands side by side, not stacked
    e2 = tr2.process(_stacked())
    assert e2[0].box != e2[1].box
