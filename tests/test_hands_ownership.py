"""Each hand's own skin pixels through an overlap (tracker/hands/ownership.py): the owner map carried by the backward
flow, the per-track colour components without the other hand's pixels, the owner map after the step, and two
synthetic hands that meet and stay touching (seeded), tracked with and without it."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.hands import ownership
from tracker.hands.features import HandFeatures
from tracker.hands.metrics import dice
from tracker.hands.tracker import HandTracker, HandTrackerConfig

SKIN = (215, 160, 130)  # RGB of a light skin tone (inside the shipped skin model's region)
TABLE = (120, 130, 140)


def _feats(mcur: np.ndarray, fb: np.ndarray, roi: tuple[int, int, int, int]) -> HandFeatures:
    """Features of an ROI with only what the owner map reads filled in: B^c_k, f^{b,1} and the components."""
    import cv2

    n, cc, stats, _ = cv2.connectedComponentsWithStats(mcur, connectivity=4, ltype=cv2.CV_32S)
    boxes = np.stack([stats[:, 0], stats[:, 1], stats[:, 0] + stats[:, 2] - 1, stats[:, 1] + stats[:, 3] - 1], 1)
    empty = np.full(mcur.shape, -1, np.int32)
    cent = np.full((4, 2), np.nan)
    return HandFeatures(roi, mcur.copy(), mcur, (fb, fb), (fb, fb), (empty, empty), (cent, cent), (empty, empty),
                        (cent, cent), cc, int(n - 1), stats[:, 4].astype(np.int64), boxes.astype(np.int64),
                        np.zeros(n, bool))  # fmt: skip


def test_owners_follow_the_backward_flow_and_stay_near_their_boxes():
    # frame k−1: hand 1 owns columns 10–19, hand 2 columns 20–29 of rows 10–19 (one touching skin region)
    prev = np.zeros((40, 60), np.int32)
    prev[10:20, 10:20] = 1
    prev[10:20, 20:30] = 2
    # frame k: both moved right by 3 px; the backward flow points 3 px left; a new column 33 came into view on the right
    mcur = np.zeros((40, 60), np.uint8)
    mcur[10:20, 13:34] = 1
    fb = np.zeros((40, 60, 2), np.float32)
    fb[..., 0] = -3.0
    feats = _feats(mcur, fb, (0, 0, 60, 40))
    states = [np.array([14.5, 14.5, 9, 9, 3, 0]), np.array([24.5, 14.5, 9, 9, 3, 0])]
    own = ownership.propagate(feats, prev, [1, 2], states)
    assert (own[10:20, 13:23] == 1).all() and (own[10:20, 23:33] == 2).all()
    assert (own[10:20, 33] == 2).all()  # came from nobody's pixel: the nearest owner of its component
    assert (own[mcur == 0] == 0).all()
    # a track that has ended owns nothing any more, and an owner is dropped far outside its (grown) box
    assert not (ownership.propagate(feats, prev, [2], states[1:]) == 1).any()
    far = [np.array([14.5, 14.5, 2, 2, 3, 0]), states[1]]
    own = ownership.propagate(feats, prev, [1, 2], far)
    assert own[15, 13] == 0 and own[15, 17] == 1  # a 2 px box at 17.5 grown by its size: columns 16–19 only
    assert ownership.propagate(feats, None, [1, 2], states) is None


def test_each_track_sees_its_own_part_of_a_shared_component():
    mcur = np.zeros((30, 40), np.uint8)
    mcur[5:15, 5:25] = 1  # one skin region
    own = np.zeros((30, 40), np.int32)
    own[5:15, 5:15] = 1
    own[5:15, 15:25] = 2
    feats = _feats(mcur, np.zeros((30, 40, 2), np.float32), (10, 20, 50, 50))
    assert feats.n_comp == 1 and ownership.shared(own, feats.cc)
    f1 = ownership.track_features(feats, own, 1, (320, 240))
    f2 = ownership.track_features(feats, own, 2, (320, 240))
    assert f1.n_comp == 1 and f1.cc_box[1].tolist() == [5, 5, 14, 14] and f1.cc_area[1] == 100
    assert f2.n_comp == 1 and f2.cc_box[1].tolist() == [15, 5, 24, 14]
    assert f1.mcur is feats.mcur and f1.labb is feats.labb  # the colour mask and the likelihood's inputs are shared
    assert not f1.cc_cut[1] and f1.cc_cut[0]
    own[5:15, 15:25] = 1  # one owner: nothing to split
    assert not ownership.shared(own, feats.cc)


def test_the_owner_map_after_the_step_claims_only_for_certain_tracks():
    mcur = np.zeros((40, 60), np.uint8)
    mcur[10:20, 10:40] = 1
    states = [np.array([17.0, 15.0, 14, 10, 0, 0]), np.array([30.0, 15.0, 16, 10, 0, 0])]  # boxes 10–24 and 22–38
    out = ownership.settle((40, 60), (0, 0, 60, 40), mcur, None, [1, 2], states)
    assert (out[10:20, 10:24] == 1).all() and (out[10:20, 24:39] == 2).all()  # in both boxes: the nearer centre
    assert (out[10:20, 39] == 0).all() and (out[mcur == 0] == 0).all()  # in no box, or no skin: nobody's
    out = ownership.settle((40, 60), (0, 0, 60, 40), mcur, None, [1, 2], states, claim=[False, True])
    assert not (out == 1).any() and (out[10:20, 22:39] == 2).all() and (out[10:20, 10:22] == 0).all()
    own = np.zeros((40, 60), np.int32)
    own[10:20, 10:26] = 1  # carried by the flow into 2's box (within 1's box grown by half its size: kept)
    out = ownership.settle((40, 60), (0, 0, 60, 40), mcur, own, [1, 2], states, claim=[True, False])
    assert (out[10:20, 10:26] == 1).all() and (out[10:20, 26:40] == 0).all()


def _meeting(t: int) -> tuple[np.ndarray, list[int], list[int]]:
    """RGB frame t and the two hands' boxes: hand A (green sleeve below) moves right and hand B (blue sleeve to the
    right) moves left, 2 px per frame, until from t = 25 on their palms overlap by 10 px (B 12 px lower): the two
    palms are one skin region from frame 21 on."""
    img = np.zeros((240, 320, 3), np.uint8) + np.uint8(TABLE)
    xa, xb = min(60 + 2 * t, 110), max(200 - 2 * t, 130)
    img[150:240, xa + 4 : xa + 26] = (20, 120, 40)
    img[122:152, xb + 30 : 320] = (40, 40, 160)
    img[110:150, xa : xa + 30] = SKIN
    img[122:162, xb : xb + 30] = SKIN
    return img, [xa, 110, xa + 30, 150], [xb, 122, xb + 30, 162]


@pytest.mark.parametrize("seed", [0, 1])
def test_two_hands_that_meet_keep_a_box_each(seed):
    def run(own: bool) -> tuple[list[float], list[float]]:
        # the filters' own boxes (the group box would report the touching hands' joint box for both)
        tr = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=seed, ownership=own, group_box=False),
                         focal=300.0)  # fmt: skip
        tr.process(np.zeros((240, 320, 3), np.uint8) + np.uint8(TABLE))
        img, box_a, box_b = _meeting(0)
        tr.process(img)
        a, b = tr.start_track(box_a), tr.start_track(box_b)
        fa, fb = [], []
        for t in range(1, 50):
            img, box_a, box_b = _meeting(t)
            ests = {e.id: e.box for e in tr.process(img)}
            fa.append(dice(ests[a], box_a) if a in ests else 0.0)
            fb.append(dice(ests[b], box_b) if b in ests else 0.0)
        return fa, fb

    fa, fb = run(True)
    assert min(fa[25:]) > 0.9 and min(fb[25:]) > 0.9  # each box on its own hand while they touch
    fa, fb = run(False)
    # without the owner map the section-6 box is the joint region or nothing, and the likelihood's border term pushes
    # each box off the other hand's skin: at least one hand's box is off while they touch
    assert min(min(fa[25:]), min(fb[25:])) < 0.85
