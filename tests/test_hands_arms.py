"""Each hand at the far end of its own arm (:mod:`tracker.hands.arm_anchor`, ``HandTrackerConfig.arm_anchor``).
Synthetic frames at scale 1 (working px = image px): a table 0.8 m away, two sleeved arms entering from the bottom
border, their hands touching or lying on each other in one skin region."""

from __future__ import annotations

import numpy as np

from tracker.hands.arm_anchor import (
    BORDER_PX,
    MIN_RUN,
    RUN_GAP,
    ArmSplit,
    _border_runs,
    _geodesic_buckets,
    _geodesic_heap,
    _one_border_run,
    arm_hands,
    arm_split,
    carried_labels,
    geodesic_labels,
    working_depth,
)
from tracker.hands.metrics import dice
from tracker.hands.skin_model import SkinModel
from tracker.hands.tracker import HandTracker, HandTrackerConfig

SKIN = (215, 160, 130)  # RGB of a light skin tone (inside the shipped skin model's region)
TABLE = (120, 130, 140)
SLEEVES = ((20, 120, 40), (40, 40, 160))
H, W = 240, 320


def _scene(hands: list[tuple[list[int], list[int], float]]) -> tuple[np.ndarray, np.ndarray]:
    """RGB and depth (m) of the table with arms drawn in order (later ones on top): each (hand box, sleeve box, depth),
    end-exclusive [u0, v0, u1, v1]; every sleeve reaches the bottom border."""
    rgb = np.zeros((H, W, 3), np.uint8) + np.uint8(TABLE)
    depth = np.full((H, W), 0.8, np.float32)
    for k, (hand, sleeve, z) in enumerate(hands):
        rgb[sleeve[1] : sleeve[3], sleeve[0] : sleeve[2]] = SLEEVES[k]
        depth[sleeve[1] : sleeve[3], sleeve[0] : sleeve[2]] = z
        rgb[hand[1] : hand[3], hand[0] : hand[2]] = SKIN
        depth[hand[1] : hand[3], hand[0] : hand[2]] = z
    return rgb, depth


TOUCHING = [([60, 110, 100, 150], [64, 150, 86, 240], 0.72), ([100, 110, 140, 150], [114, 150, 136, 240], 0.72)]
"""Two hands side by side in one skin region (each 40 × 40 px), each on its sleeve."""
STACKED = [([50, 110, 100, 150], [55, 150, 77, 240], 0.72), ([80, 100, 130, 150], [100, 150, 122, 240], 0.66)]
"""Hand B (6 cm nearer the camera) lying over the right part of hand A: A shows only its left 30 px."""


def _inclusive_to_excl(b) -> list[int]:
    return [b[0], b[1], b[2] + 1, b[3] + 1]


def _hands(scene) -> list:
    rgb, depth = scene
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    bg = working_depth(np.full((H, W), 0.8), 1, (H, W))
    return sorted(arm_hands(skin, working_depth(depth, 1, (H, W)), bg), key=lambda h: h.entry[0])


def test_geodesic_labels_do_not_cross_a_depth_step_when_a_flat_way_round_exists():
    mask = np.ones((5, 9), np.uint8)
    z = np.full((5, 9), 0.7)
    z[:4, 4] = 0.6  # a ridge 10 cm nearer, open at the bottom row
    seeds = np.zeros((5, 9), np.int32)
    seeds[0, 0] = 1
    lab, dist = geodesic_labels(mask, z, seeds, 0.012, 20.0)
    assert np.all(lab == 1)
    assert dist[0, 8] == 16.0  # round the ridge through the bottom row: 4 down, 8 across, 4 up
    assert dist[0, 4] == 24.0  # 3 flat steps, then one onto the ridge of cost 1 + 20
    lab2, _ = geodesic_labels(mask, z, np.zeros((5, 9), np.int32), 0.012, 20.0)
    assert not lab2.any()


def test_one_border_run_agrees_with_the_runs_of_the_border_pixels():
    """The compiled run test (used per arm) says "one run" exactly when the NumPy grouping (``_border_runs``, which
    the split of crossing arms uses) finds one run, on random
    border pixel sets: runs along each edge, through corners and through the top-left corner where the perimeter
    coordinate wraps."""
    rng = np.random.default_rng(0)
    h, w = 24, 32
    band = [(y, x) for y in range(h) for x in range(w) if y < BORDER_PX or y >= h - BORDER_PX or x < BORDER_PX
            or x >= w - BORDER_PX]  # fmt: skip
    counts = {0: 0, 1: 0, 2: 0}
    for _ in range(300):
        pick = rng.random(len(band)) < rng.choice([0.05, 0.2, 0.6])
        if rng.random() < 0.3:  # one contiguous stretch of the perimeter, maybe through the top-left corner
            start = int(rng.integers(len(band)))
            pick[:] = False
            pick[[(start + k) % len(band) for k in range(int(rng.integers(3, 30)))]] = True
        if not pick.any():
            continue
        ys = np.array([band[i][0] for i in np.nonzero(pick)[0]])
        xs = np.array([band[i][1] for i in np.nonzero(pick)[0]])
        n_runs = len(_border_runs(ys, xs, h, w))
        counts[min(n_runs, 2)] += 1
        assert _one_border_run(ys, xs, h, w, BORDER_PX, RUN_GAP, MIN_RUN) == (n_runs == 1)
    assert min(counts.values()) > 10  # every case occurred


def test_bucket_queue_geodesic_equals_the_heap_one():
    """Labels and distances of the bucket queue (whole-number step cost) equal the binary heap's on random masks,
    depths with steps and seeds, ties included (small masks: many equal distances)."""
    rng = np.random.default_rng(1)
    reached = 0
    for _ in range(100):
        h, w = (int(v) for v in rng.integers(5, 30, 2))
        mask = (rng.random((h, w)) < 0.8).astype(np.uint8)
        z = np.where(rng.random((h, w)) < 0.2, 0.6, 0.7) * (rng.random((h, w)) < 0.95)
        seeds = np.zeros((h, w), np.int32)
        seeds[rng.integers(0, h, 4), rng.integers(0, w, 4)] = rng.integers(1, 4, 4)
        prev = rng.integers(0, 4, (h, w)).astype(np.int32)
        grey = rng.choice(np.array([100, 104, 120, 160], np.uint8), (h, w))
        for cost, keep, thr, slope in ((20.0, 0.0, 0, 0), (0.0, 0.0, 0, 0), (3.0, 0.0, 0, 0), (20.0, 2.0, 0, 0),
                                       (0.0, 5.0, 0, 0), (20.0, 2.0, 10, 1), (3.0, 0.0, 5, 3)):  # fmt: skip
            lab_h, dist_h = _geodesic_heap(mask, z, seeds, 0.012, cost, prev, keep, grey, thr, slope)
            lab_b, dist_b = _geodesic_buckets(mask, z, seeds, 0.012, cost, prev, keep, grey, thr, slope)
            assert np.array_equal(lab_h, lab_b) and np.array_equal(dist_h, dist_b)
            reached += int(np.count_nonzero(lab_b))
    assert reached > 10000


def test_geodesic_labels_pay_for_crossing_a_grey_level_edge():
    """A column whose grey level differs from its neighbours by 30, open at the bottom row: with edge_slope 2 above
    edge_thr 10 each crossing costs 1 + 2 · 20, so the way round is shorter; without ``grey`` (or slope 0) straight
    across. The cost counts on both sides of the column (into it and out of it)."""
    mask = np.ones((5, 9), np.uint8)
    z = np.full((5, 9), 0.7)
    grey = np.full((5, 9), 120, np.uint8)
    grey[:4, 4] = 150
    seeds = np.zeros((5, 9), np.int32)
    seeds[0, 0] = 1
    _, dist = geodesic_labels(mask, z, seeds, 0.012, 20.0, grey=grey, edge_thr=10, edge_slope=2)
    assert dist[0, 8] == 16.0  # round through the bottom row
    assert dist[0, 4] == 3.0 + 41.0  # 3 flat steps, then into the column: 1 + 2 · (30 − 10)
    for kw in ({}, {"grey": grey, "edge_thr": 10, "edge_slope": 0}):
        _, plain = geodesic_labels(mask, z, seeds, 0.012, 20.0, **kw)
        assert plain[0, 8] == 8.0 and plain[0, 4] == 4.0


def _touching_split():
    """The TOUCHING scene's skin mask, working depth and background, its fresh two-arm split (hands and the split) and
    the index of the left arm."""
    rgb, depth = _scene(TOUCHING)
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    z = working_depth(depth, 1, (H, W))
    bg = working_depth(np.full((H, W), 0.8), 1, (H, W))
    fresh, split = arm_split(skin, z, bg)
    assert split is not None and len(fresh) == 2
    return skin, z, bg, fresh, split, int(np.argmin(split.entries[:, 0]))


def test_the_previous_split_keeps_its_labels_where_two_touching_hands_meet(monkeypatch):
    """Two hands side by side at one depth: afresh, the split falls where the two wrists are equally far (x ≈ 100);
    with the previous frame's split giving the left arm 10 more columns, KEEP_COST per pixel keeps part of them, and
    with KEEP_COST 0 (off) the previous split changes nothing."""
    from tracker.hands import arm_anchor

    skin, z, bg, fresh, split, left = _touching_split()
    assert abs(fresh[left].box[2] - 99) <= 2
    # the previous split lists the same arms the other way round: there the left arm is label 2 - left
    prev_labels = np.where(skin > 0, left + 1, 0).astype(np.int32)
    prev_labels[:, :110][skin[:, :110] > 0] = 2 - left
    prev = ArmSplit(prev_labels, split.entries[::-1].copy())
    assert np.array_equal(carried_labels(prev, split.entries)[skin > 0], np.where(np.arange(W) < 110, left + 1,
                                                                                  2 - left)[np.nonzero(skin)[1]])
    monkeypatch.setattr(arm_anchor, "KEEP_COST", 0.0)
    assert [h.box for h in arm_split(skin, z, bg, prev)[0]] == [h.box for h in fresh]
    monkeypatch.setattr(arm_anchor, "KEEP_COST", 2.0)
    kept = arm_split(skin, z, bg, prev)[0]
    # the left arm's label spreads 1 px a step into those columns, the right arm's 1 + 2: the meeting moves to x ≈ 105
    assert kept[left].box[2] >= fresh[left].box[2] + 4 and kept[1 - left].box[0] >= fresh[1 - left].box[0] + 4


def test_two_touching_hands_are_split_at_the_ends_of_their_arms():
    hands = _hands(_scene(TOUCHING))
    assert len(hands) == 2
    for hd, (hand, sleeve, _) in zip(hands, TOUCHING, strict=True):
        assert sleeve[0] <= hd.entry[0] <= sleeve[2] and hd.entry[1] > H - 3  # entered through the bottom border
        assert dice(_inclusive_to_excl(hd.box), hand) > 0.9
    union = [60, 110, 140, 150]
    assert dice(_inclusive_to_excl(hands[0].box), union) < 0.7


def test_the_upper_hand_is_split_from_the_lower_one_by_the_depth_step():
    hands = _hands(_scene(STACKED))
    assert len(hands) == 2
    visible_a = [50, 110, 80, 150]
    assert dice(_inclusive_to_excl(hands[0].box), visible_a) > 0.9
    assert dice(_inclusive_to_excl(hands[1].box), STACKED[1][0]) > 0.9


def test_the_blind_band_along_the_upper_hand_splits_it_from_the_lower_one(monkeypatch):
    """Hands at one depth, B lying over A's upper right and reaching left, nearer A's wrist than its own: only the
    sensor's band without depth along B's edge over A (HOLE_STEP) tells them apart."""
    from tracker.hands import arm_anchor

    a_hand, b_hand = [50, 110, 100, 150], [70, 80, 130, 130]
    rgb, depth = _scene([(a_hand, [55, 150, 77, 240], 0.72), (b_hand, [110, 130, 132, 240], 0.72)])
    depth[110:130, 70] = np.nan  # B's left edge over A
    depth[129, 70:100] = np.nan  # B's lower edge over A
    got = {}
    for hole in (True, False):
        monkeypatch.setattr(arm_anchor, "HOLE_STEP", hole)
        hands = _hands((rgb, depth))
        assert len(hands) == 2
        got[hole] = _inclusive_to_excl(hands[1].box)
    assert dice(got[True], b_hand) > 0.95
    assert dice(got[False], b_hand) < 0.9  # without it A's wrist takes B's left part


def test_a_one_centimetre_step_splits_the_upper_hand_from_the_lower_one(monkeypatch):
    """Hand B lies 1 cm above hand A (a flat hand on a flat hand), over A's upper right and reaching left, nearer A's
    wrist than its own, no band without depth: the depth step (DEPTH_STEP 0.008 m, DEPTH_STEP_COST 40) keeps B's left
    part with B's wrist; with session 24's 0.012 m / 20 the 1 cm edge is no step and A's wrist takes it."""
    from tracker.hands import arm_anchor

    a_hand, b_hand = [50, 110, 100, 150], [70, 80, 130, 130]
    scene = _scene([(a_hand, [55, 150, 77, 240], 0.72), (b_hand, [110, 130, 132, 240], 0.71)])
    assert arm_anchor.DEPTH_STEP == 0.008 and arm_anchor.DEPTH_STEP_COST == 40.0
    got = {}
    for step, cost in ((0.008, 40.0), (0.012, 20.0)):
        monkeypatch.setattr(arm_anchor, "DEPTH_STEP", step)
        monkeypatch.setattr(arm_anchor, "DEPTH_STEP_COST", cost)
        hands = _hands(scene)
        assert len(hands) == 2
        got[step] = _inclusive_to_excl(hands[1].box)
    assert dice(got[0.008], b_hand) > 0.95
    assert dice(got[0.012], b_hand) < 0.9


def _crossing(hands_apart: bool = True) -> tuple[np.ndarray, np.ndarray, list[tuple[float, float]]]:
    """RGB and depth of two sleeved forearms crossing in an X (arm A from the bottom-left corner up to the right, arm
    B from the bottom-right up to the left, lying on A, 4 cm nearer the camera), one sleeve region that meets the
    bottom border in two runs; each hand (a disc of radius 16 px) beyond its sleeve's end. Returns (rgb, depth,
    [A's hand centre, B's hand centre]); ``hands_apart`` False: the hands' discs overlap (one skin region)."""
    import cv2

    rgb = np.zeros((H, W, 3), np.uint8) + np.uint8(TABLE)
    depth = np.full((H, W), 0.8, np.float32)
    ends = [((30, 239), (210, 90)), ((290, 239), (110, 90))] if hands_apart else [((30, 239), (170, 110)),
                                                                                   ((290, 239), (150, 110))]
    centres = []
    for k, ((x0, y0), (x1, y1)) in enumerate(ends):
        cv2.line(rgb, (x0, y0), (x1, y1), SLEEVES[k], 24)
        cv2.line(depth, (x0, y0), (x1, y1), 0.70 - 0.04 * k, 24)
        d = np.array([x1 - x0, y1 - y0], float)
        c = np.array([x1, y1]) + 26 * d / np.hypot(*d) if hands_apart else np.array([174.0 - 28.0 * k, 84.0])
        centres.append((float(c[0]), float(c[1])))
    for c, z in zip(centres, (0.70, 0.66), strict=True):
        cv2.circle(rgb, (round(c[0]), round(c[1])), 16, SKIN, -1)
        cv2.circle(depth, (round(c[0]), round(c[1])), 16, z, -1)
    return rgb, depth, centres


def test_two_crossing_forearms_each_find_their_own_hand(monkeypatch):
    """Two forearms crossing in an X form one sleeve region meeting the border in two runs; the tube per run
    (``CROSS_SPLIT``) gives each arm the hand beyond its own sleeve's end (A, entering bottom-left, the right hand),
    also across the crossing where A lies under B; without it the region is dropped and no arm is found."""
    from tracker.hands import arm_anchor

    rgb, depth, (ca, cb) = _crossing()
    hands = _hands((rgb, depth))
    assert len(hands) == 2
    a, b = hands  # sorted by entry x: A enters at the left
    assert a.entry[0] < 80 and b.entry[0] > 240 and a.entry[1] > H - 3 and b.entry[1] > H - 3
    for hd, c in ((a, ca), (b, cb)):
        assert dice(_inclusive_to_excl(hd.box), [c[0] - 16, c[1] - 16, c[0] + 17, c[1] + 17]) > 0.85
    monkeypatch.setattr(arm_anchor, "CROSS_SPLIT", False)
    assert _hands((rgb, depth)) == []


def test_crossing_forearms_whose_hands_touch_are_not_split(monkeypatch):
    """The same X with the two hands touching in one skin region: both tubes' wrists reach it, and which hand is
    whose is not told by the tubes, so no arm is reported (``CROSS_TOUCH_DROP``); with it off both are."""
    import cv2

    from tracker.hands import arm_anchor

    rgb, depth, _ = _crossing(hands_apart=False)
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    assert cv2.connectedComponents(skin.astype(np.uint8), connectivity=8)[0] == 2  # background + one skin region
    assert _hands((rgb, depth)) == []
    monkeypatch.setattr(arm_anchor, "CROSS_TOUCH_DROP", False)
    assert len(_hands((rgb, depth))) == 2


def test_no_depth_change_no_arms():
    rgb, depth = _scene(TOUCHING)
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    z = working_depth(depth, 1, (H, W))
    assert arm_hands(skin, z, z.copy()) == []  # the background is this frame: nothing in front of it
    assert arm_hands(np.zeros((H, W), np.uint8), z, np.full((H, W), 0.8)) == []


def _tracker(arm: bool) -> HandTracker:
    tr = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=0, arm_anchor=arm))
    table = _scene([])
    tr.process(*table)
    return tr


def test_each_track_reports_the_hand_at_the_end_of_its_own_arm():
    """Two tracks started on the two touching hands keep reporting each hand's own box, also after their filters
    are put on each other's hands (the arm, not the filter, says which hand is whose)."""
    scene = _scene(TOUCHING)
    boxes = {}
    for arm in (True, False):
        tr = _tracker(arm)
        tr.process(*scene)
        a = tr.start_track(TOUCHING[0][0])
        b = tr.start_track(TOUCHING[1][0])
        ests = {e.id: e.box for e in tr.process(*scene)}
        if arm:
            assert set(tr._entries) == {a, b}
            assert tr._entries[a][0] < tr._entries[b][0]  # a's arm enters left of b's
            assert dice(ests[a], TOUCHING[0][0]) > 0.9 and dice(ests[b], TOUCHING[1][0]) > 0.9
        sa, sb = tr.tracks[0].filt.estimate.copy(), tr.tracks[1].filt.estimate.copy()
        tr.tracks[0].filt.set_state(sb)  # the filters swap hands
        tr.tracks[1].filt.set_state(sa)
        boxes[arm] = {e.id: e.box for e in tr.process(*scene)}
    assert dice(boxes[True][a], TOUCHING[0][0]) > 0.9 and dice(boxes[True][b], TOUCHING[1][0]) > 0.9
    assert dice(boxes[False][a], TOUCHING[0][0]) < 0.8  # without the arms the filters' boxes (grown over both)


APART = [([40, 110, 80, 150], [49, 150, 71, 240], 0.72), ([200, 110, 240, 150], [209, 150, 231, 240], 0.72)]
"""Two hands 120 px apart, each on its sleeve."""


def _arm_runs(hands: list, near: float | None, every: int, frames: int, monkeypatch) -> int:
    """How often the arm detector runs over ``frames`` frames of a static scene of ``hands`` with two tracks started
    on their boxes."""
    from tracker.hands import arm_anchor

    calls = []
    real = arm_anchor.arm_split
    monkeypatch.setattr(arm_anchor, "arm_split", lambda *a, **k: calls.append(1) or real(*a, **k))
    tr = HandTracker(HandTrackerConfig(auto_init=False, scale=1, seed=0, arm_near_px=near, arm_every=every))
    scene = _scene(hands)
    tr.process(*_scene([]))
    tr.process(*scene)
    for hand, _, _ in hands:
        tr.start_track(hand)
    for _ in range(frames):
        tr.process(*scene)
    return len(calls)


def test_the_arm_detector_rests_while_two_agreeing_tracks_are_apart(monkeypatch):
    assert _arm_runs(APART, None, 1, 7, monkeypatch) == 7  # every frame
    assert _arm_runs(APART, 0.0, 3, 7, monkeypatch) == 3  # frames 1, 4, 7: the filters agree with their arms
    assert _arm_runs(STACKED, 0.0, 3, 7, monkeypatch) == 7  # overlapping boxes: every frame


def _two_touching_tracks(scene):
    """A tracker (arm detector on) that has seen ``scene`` once, with a track started on each of the two TOUCHING
    hands' boxes and one more frame processed: (tracker, id of hand 0's track, id of hand 1's track)."""
    tr = _tracker(True)
    tr.process(*scene)
    a = tr.start_track(TOUCHING[0][0])
    b = tr.start_track(TOUCHING[1][0])
    tr.process(*scene)
    return tr, a, b


def test_a_track_whose_remembered_arm_entry_went_stale_takes_its_arm_again(monkeypatch):
    """A track whose remembered arm entry lies far from every arm (its arm went round the image corner, or a split
    sleeve gave it a piece of the arm) takes the unclaimed arm whose hand box matches its box again (ARM_RELEARN);
    without the re-learning the stale entry stays and the track gets no arm for the rest of the session."""
    import tracker.hands.tracker as hand_tracker

    scene = _scene(TOUCHING)
    for relearn in (True, False):
        monkeypatch.setattr(hand_tracker, "ARM_RELEARN", relearn)
        tr, a, b = _two_touching_tracks(scene)
        learnt = tr._entries[a]
        stale = (float(W - 1), 100.0)  # on the right border, far from both arms
        tr._entries[a] = stale
        ests = {e.id: e.box for e in tr.process(*scene)}
        if relearn:
            assert np.hypot(tr._entries[a][0] - learnt[0], tr._entries[a][1] - learnt[1]) < 2.0
            assert dice(ests[a], TOUCHING[0][0]) > 0.9
        else:
            assert tr._entries[a] == stale
        assert dice(ests[b], TOUCHING[1][0]) > 0.9


def test_two_merged_tracks_that_each_have_their_own_arm_are_both_kept(monkeypatch):
    """Two established tracks whose filters have shared one box for MERGED_KEEP frames lose the worse one, unless
    the arm detector's last run gave each its own arm (ARM_KEEP_MERGED): the two hands lie on each other and are both
    still found (traced on ``hands-s2`` tuning seed 3: a hand's track ended after 120 merged frames while its arm was
    found, 49 hand-frames without a box and the other track's box over both hands)."""
    import tracker.hands.tracker as hand_tracker

    scene = _scene(TOUCHING)
    for keep_merged in (True, False):
        monkeypatch.setattr(hand_tracker, "ARM_KEEP_MERGED", keep_merged)
        tr, a, b = _two_touching_tracks(scene)
        assert tr._arm_own == {a, b}  # the detector found each track's arm
        both = np.array([100.0, 129.5, 80.0, 40.0, 0.0, 0.0])  # one box over the two hands
        for t in tr.tracks:
            t.filt.set_state(both)
            t.apart = hand_tracker.ESTABLISHED
        tr.tracks[0].dup = {tr.tracks[1].id: hand_tracker.MERGED_KEEP - 1}
        keep = tr._terminate((W, H))
        assert sum(keep) == (2 if keep_merged else 1)


def test_the_hand_box_covers_the_rim_that_the_opening_trims(monkeypatch):
    """A hand with a one-pixel-wide spike of skin sticking out of its left side (a finger's edge where the colour mask
    is one pixel wide): the split runs on the mask opened by a 3 × 3 cross, which keeps only the spike's first pixel;
    with BOX_RIM the hand's box also takes the unopened skin within RIM_PX of its pixels (two more columns with RIM_PX
    2, one with 1), without it the box starts at the spike's first pixel."""
    from tracker.hands import arm_anchor

    hand, sleeve = [60, 110, 100, 150], [64, 150, 86, 240]
    rgb, depth = _scene([(hand, sleeve, 0.72)])
    rgb[130, 52:60] = SKIN  # the spike, at the hand's depth
    depth[130, 52:60] = 0.72
    boxes = {}
    for rim, px in ((True, 2), (True, 1), (False, 2)):
        monkeypatch.setattr(arm_anchor, "BOX_RIM", rim)
        monkeypatch.setattr(arm_anchor, "RIM_PX", px)
        hands = _hands((rgb, depth))
        assert len(hands) == 1
        boxes[rim, px] = hands[0].box
    assert boxes[True, 2] == (57, 110, 99, 149)
    assert boxes[True, 1] == (58, 110, 99, 149)
    assert boxes[False, 2] == (59, 110, 99, 149)


def test_the_flow_moves_the_split_to_where_the_two_motions_meet(monkeypatch):
    """Two hands side by side at one depth, split afresh where the two wrists are equally far (x ≈ 100). A flow in which
    the left hand's motion (1, 0) px per frame reaches on to x = 112 and the right hand stands still: with
    MOTION_SPLIT the left arm keeps the columns that move with it; with MOTION_SPLIT off (explicitly), or with two
    motions closer than MOTION_SEP, the flow changes nothing."""
    from tracker.hands import arm_anchor

    skin, z, bg, fresh, split, left = _touching_split()
    x0, y0 = 40, 90  # the flow covers a region of the image (the tracker's ROI)
    f = np.zeros((100, 130, 2), np.float32)
    f[:, : 112 - x0, 0] = 1.0
    monkeypatch.setattr(arm_anchor, "MOTION_SPLIT", False)
    assert [h.box for h in arm_split(skin, z, bg, None, (f, x0, y0))[0]] == [h.box for h in fresh]
    monkeypatch.setattr(arm_anchor, "MOTION_SPLIT", True)
    moved = arm_split(skin, z, bg, None, (f, x0, y0))[0]
    # the right arm pays 1 + MOTION_COST a column into x < 112, the left 1: they meet ≈ 6 columns further right
    assert moved[left].box[2] >= fresh[left].box[2] + 5 and moved[1 - left].box[0] >= fresh[1 - left].box[0] + 5
    assert moved[left].box[2] <= 112 and moved[1 - left].box[0] <= 113
    alike = f * np.float32(0.5 * arm_anchor.MOTION_SEP)
    assert [h.box for h in arm_split(skin, z, bg, None, (alike, x0, y0))[0]] == [h.box for h in fresh]


def test_the_tracker_gives_the_arm_detector_its_frame_flow(monkeypatch):
    """The tracker passes the arm detector the backward flow of its ROI with the ROI's top-left working px (what
    MOTION_SPLIT clusters): the flow array of the frame's features, at the features' ROI origin."""
    from tracker.hands import arm_anchor

    seen = []
    real = arm_anchor.arm_split
    monkeypatch.setattr(arm_anchor, "arm_split", lambda *a, **k: seen.append(a[4]) or real(*a, **k))
    tr, _, _ = _two_touching_tracks(_scene(TOUCHING))
    assert seen and seen[-1] is not None
    f, x0, y0 = seen[-1]
    ft = tr.last_features
    assert ft is not None and f is ft.fb[0] and (x0, y0) == (ft.roi[0], ft.roi[1])
    assert f.shape[:2] == (ft.roi[3] - ft.roi[1], ft.roi[2] - ft.roi[0]) and f.shape[2] == 2


def test_a_shading_edge_between_two_touching_hands_splits_them_there(monkeypatch):
    """Two hands side by side at one depth, hand A reaching 12 columns past the point where the two wrists are equally
    far (x ≈ 100) and hand B in shade (20 grey levels darker): with EDGE_SPLIT the split follows the shading edge at
    x = 112, without it (off, explicitly, or no grey image passed) it falls where the wrists are equally far."""
    import cv2

    from tracker.hands import arm_anchor

    rgb, depth = _scene([([60, 110, 112, 150], [64, 150, 86, 240], 0.72), ([112, 110, 140, 150], [114, 150, 136, 240],
                                                                          0.72)])  # fmt: skip
    rgb[110:150, 112:140] = (190, 141, 115)  # B in shade
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    assert skin[110:150, 60:140].all()  # both tones are skin
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    z = working_depth(depth, 1, (H, W))
    bg = working_depth(np.full((H, W), 0.8), 1, (H, W))

    def boxes(on: bool, g) -> list[tuple[int, int, int, int]]:
        monkeypatch.setattr(arm_anchor, "EDGE_SPLIT", on)
        hands = sorted(arm_split(skin, z, bg, grey=g)[0], key=lambda hd: hd.entry[0])
        assert len(hands) == 2
        return [hd.box for hd in hands]

    on = boxes(True, grey)
    assert on[0][2] == 111 and on[1][0] == 112
    off = boxes(False, grey)
    assert abs(off[0][2] - 99) <= 2 and abs(off[1][0] - 100) <= 2
    assert boxes(True, None) == off


def test_the_tracker_gives_the_arm_detector_its_grey_frame(monkeypatch):
    """The tracker passes the arm detector the working frame's grey levels (what EDGE_SPLIT reads)."""
    import cv2

    from tracker.hands import arm_anchor

    seen = []
    real = arm_anchor.arm_split
    monkeypatch.setattr(arm_anchor, "arm_split", lambda *a, **k: seen.append(a[5]) or real(*a, **k))
    rgb, depth = _scene(TOUCHING)
    _two_touching_tracks((rgb, depth))
    assert seen and seen[-1] is not None
    assert np.array_equal(seen[-1], cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


def test_seeds_the_previous_split_gave_another_arm_are_vetoed(monkeypatch):
    """Arm B's sleeve also runs under the right part of hand A (rows 150–155, x 92–135), so B's wrist seeds include A's
    bottom row there and B takes A's right columns; with SEED_VETO and the previous frame's split (A up to x 99) those
    seeds go and A keeps its columns. Off, or without a previous split, the veto changes nothing."""
    from tracker.hands import arm_anchor

    rgb, depth = _scene(TOUCHING)
    rgb[150:156, 92:136] = SLEEVES[1]
    depth[150:156, 92:136] = 0.72
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    z = working_depth(depth, 1, (H, W))
    bg = working_depth(np.full((H, W), 0.8), 1, (H, W))
    fresh, split = arm_split(skin, z, bg)
    assert split is not None and len(fresh) == 2
    a = int(np.argmin(split.entries[:, 0]))
    assert fresh[1 - a].box[0] <= 92  # afresh B reaches into A's columns from the seeds under A
    labels = np.where(skin > 0, np.where(np.arange(W)[None, :] < 100, a + 1, 2 - a), 0).astype(np.int32)
    prev = ArmSplit(labels, split.entries.copy())
    monkeypatch.setattr(arm_anchor, "SEED_VETO", False)
    kept = arm_split(skin, z, bg, prev)[0]
    assert kept[1 - a].box[0] <= 92  # the previous split's KEEP_COST alone does not stop a seed (it costs nothing)
    monkeypatch.setattr(arm_anchor, "SEED_VETO", True)
    vetoed = arm_split(skin, z, bg, prev)[0]
    assert vetoed[1 - a].box[0] >= 96 and vetoed[a].box[2] >= 96
    assert [h.box for h in arm_split(skin, z, bg)[0]] == [h.box for h in fresh]  # no previous split: no veto


def test_an_arm_whose_seeds_would_all_be_vetoed_keeps_them():
    from tracker.hands.arm_anchor import vetoed_seeds

    seeds = np.zeros((4, 6), np.int32)
    seeds[0, :3] = 1
    seeds[3, :] = 2
    carried = np.zeros((4, 6), np.int32)
    carried[0, :3] = 2  # all of arm 1's seeds lay in arm 2's region last frame: kept
    carried[3, :2] = 1  # two of arm 2's six seeds lay in arm 1's region: dropped
    out = vetoed_seeds(seeds, carried, 2)
    assert np.array_equal(out[0], seeds[0]) and out[3].tolist() == [0, 0, 2, 2, 2, 2]
    assert seeds[3, 0] == 2  # the input is not changed


FOLDED = [([64, 150, 86, 240], SLEEVES[0], 0.70), ([60, 110, 100, 150], SKIN, 0.72),
          ([112, 162, 134, 240], SLEEVES[1], 0.66), ([84, 100, 140, 162], SKIN, 0.66)]  # fmt: skip
"""Arm A's sleeve (2 cm in front of its hand: the cuff covers the wrist) and hand, then arm B's sleeve and hand B lying
over A's hand's right part and the top right corner of A's sleeve, 4 cm in front of it (box, colour, depth m)."""


def test_wrist_seeds_on_a_hand_lying_over_the_sleeve_end_are_dropped(monkeypatch):
    """Hand B lies over the end of arm A's sleeve, so A's wrist also seeds B's left edge: without SEED_BEHIND A's label
    takes the lower left part of B; with it the seeds whose skin is not behind A's sleeve go, and A keeps its own
    visible hand (the columns left of B) while B gets all of its own."""
    from tracker.hands import arm_anchor

    rgb = np.zeros((H, W, 3), np.uint8) + np.uint8(TABLE)
    depth = np.full((H, W), 0.8, np.float32)
    for box, colour, z in FOLDED:
        rgb[box[1] : box[3], box[0] : box[2]] = colour
        depth[box[1] : box[3], box[0] : box[2]] = z
    boxes = {}
    for on in (False, True):
        monkeypatch.setattr(arm_anchor, "SEED_BEHIND", on)
        hands = _hands((rgb, depth))
        assert len(hands) == 2
        boxes[on] = [h.box for h in hands]
    assert boxes[False][0][2] >= 100 and boxes[False][1][0] >= 95  # A's label reaches into B
    assert boxes[True] == [(60, 110, 83, 149), (84, 100, 139, 161)]


def test_behind_seeds_keep_seeds_behind_the_sleeve_or_without_depth_and_an_arm_keeps_its_last():
    """Per seed the skin and sleeve depth medians within BEHIND_R px: a seed whose skin lies 2 cm behind the sleeve
    stays, one at the sleeve's depth goes, one without sleeve depth around it stays; an arm all of whose seeds would
    go keeps them."""
    from tracker.hands.arm_anchor import behind_seeds

    sk = np.zeros((12, 30), np.uint8)
    sleeve = np.zeros((12, 30), np.uint8)
    sk[:6] = 1
    sleeve[6:] = 1
    z = np.full((12, 30), 0.70)
    z[:6, :10] = 0.72  # behind the sleeve
    z[6:, 20:] = 0.0  # no sleeve depth
    seeds = np.zeros((12, 30), np.int32)
    seeds[5, 5] = seeds[5, 15] = seeds[5, 25] = 1
    seeds[5, 14] = 2  # arm 2's only seed, at the sleeve's depth
    out = behind_seeds(seeds, sk, sleeve, z, 2)
    assert out[5, 5] == 1 and out[5, 15] == 0 and out[5, 25] == 1 and out[5, 14] == 2
    assert seeds[5, 15] == 1  # the input is not changed


def test_an_arm_whose_hand_the_other_arm_took_is_reseeded_from_the_previous_split(monkeypatch):
    """Arm A's sleeve ends 8 px below its hand and touches only a small skin blob there (a finger of the other hand
    peeking past it; 3 px of table between it and hand A), while hand A touches hand B: afresh A's wrist seeds only
    the blob and B's label takes both hands. With STOLEN_RESEED and the previous frame's split (A held its hand) A's
    previous pixels seed it again and A gets its hand back; off, or without a previous split, nothing changes."""
    from tracker.hands import arm_anchor

    rgb = np.zeros((H, W, 3), np.uint8) + np.uint8(TABLE)
    depth = np.full((H, W), 0.8, np.float32)
    for box, colour, z in (([64, 158, 86, 240], SLEEVES[0], 0.72), ([60, 110, 100, 150], SKIN, 0.72),
                           ([100, 110, 140, 150], SKIN, 0.72), ([114, 150, 136, 240], SLEEVES[1], 0.72),
                           ([68, 153, 82, 158], SKIN, 0.72)):  # fmt: skip
        rgb[box[1] : box[3], box[0] : box[2]] = colour
        depth[box[1] : box[3], box[0] : box[2]] = z
    skin = SkinModel.load().with_threshold(-2.0).mask(rgb)
    z = working_depth(depth, 1, (H, W))
    bg = working_depth(np.full((H, W), 0.8), 1, (H, W))
    fresh, split = arm_split(skin, z, bg)
    assert split is not None and len(split.entries) == 2
    a = int(np.argmin(split.entries[:, 0]))
    by_entry = {int(h.entry[0] >= 100): h.box for h in fresh}
    assert by_entry[0][1] >= 148 and by_entry[1][0] <= 62  # afresh A keeps only the blob, B takes both hands
    labels = np.where(skin > 0, np.where(np.arange(W)[None, :] < 100, a + 1, 2 - a), 0).astype(np.int32)
    prev = ArmSplit(labels, split.entries.copy())
    boxes = {}
    for on in (False, True):
        monkeypatch.setattr(arm_anchor, "STOLEN_RESEED", on)
        boxes[on] = {int(h.entry[0] >= 100): h.box for h in arm_split(skin, z, bg, prev)[0]}
    assert boxes[False] == by_entry  # off: the previous split's KEEP_COST alone does not give A its hand back
    assert boxes[True][0][:2] == (60, 110) and boxes[True][0][2] >= 97 and boxes[True][1][0] >= 99
    assert {int(h.entry[0] >= 100): h.box for h in arm_split(skin, z, bg)[0]} == by_entry  # no previous split


def test_stolen_seeds_reseed_only_an_arm_whose_previous_pixels_the_other_arm_took():
    """Arm 2's label took all of arm 1's previous pixels while arm 1's wrist seeds a separate blob: arm 1 gets the
    eroded core of its previous pixels as seeds. Not when arm 1 kept a third of them, when nothing changed, or when its
    wrist seeds lie in the region of its previous pixels (the new split may be putting a wrong previous one right)."""
    from tracker.hands.arm_anchor import stolen_seeds

    sk = np.zeros((20, 40), np.uint8)
    sk[2:18, 2:38] = 1
    sk[19, 8:13] = 1  # a separate blob at arm 1's wrist
    carried = np.zeros((20, 40), np.int32)
    carried[2:18, 2:20] = 1
    carried[2:18, 20:38] = 2
    seeds = np.zeros((20, 40), np.int32)
    seeds[17, 30] = 2
    seeds[19, 10] = 1
    labels = np.where(sk > 0, 2, 0).astype(np.int32)  # arm 2 took all of arm 1's previous pixels
    labels[19] = np.where(sk[19] > 0, 1, 0)
    out = stolen_seeds(labels, carried, sk, seeds)
    assert out is not None and out[10, 10] == 1 and out[2, 2] == 0 and out[10, 30] == 0  # eroded core of arm 1's
    assert out[19, 10] == 1 and out[17, 30] == 2 and seeds[10, 10] == 0  # the wrist seeds kept, the input unchanged
    inside = seeds.copy()
    inside[19, 10] = 0
    inside[17, 10] = 1  # arm 1's wrist seeds the region of its previous pixels
    assert stolen_seeds(labels, carried, sk, inside) is None
    labels[2:18, 2:8] = 1  # arm 1 kept a third of its pixels: not taken
    assert stolen_seeds(labels, carried, sk, seeds) is None
    assert stolen_seeds(np.where(sk > 0, carried, 0).astype(np.int32), carried, sk, seeds) is None  # as before
