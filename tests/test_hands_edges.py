"""The reported hand box's colour edges placed at full resolution (``HandTrackerConfig.edge_refine``,
:mod:`tracker.hands.edge_refine`)."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.hands import edge_refine
from tracker.hands.edge_refine import refine_box
from tracker.hands.metrics import centre_error
from tracker.hands.tracker import HandTracker, HandTrackerConfig
from tracker.sources.simulator import SimulatedTable


def _mask_of(mask: np.ndarray):
    return lambda x0, y0, x1, y1: mask[y0:y1, x0:x1]


def test_edges_move_to_the_full_resolution_skin():
    mask = np.zeros((60, 80), np.uint8)
    mask[20:40, 11:31] = 1  # skin columns 11..30, rows 20..39
    # a box one px short on the left and right (working-pixel ends) and one px too low at the bottom
    assert refine_box([12, 20, 30, 41], _mask_of(mask), (80, 60), 2) == [11, 20, 31, 40]
    # an edge 3 px inside the skin (more than `grow`) sees skin beyond the band: it stays
    assert refine_box([14, 20, 31, 40], _mask_of(mask), (80, 60), 2) == [14, 20, 31, 40]


def test_an_edge_where_the_skin_goes_on_is_kept(monkeypatch):
    mask = np.zeros((60, 80), np.uint8)
    mask[20:40, 11:70] = 1  # a bare forearm: the skin goes on past the right edge (a wrist cut)
    # ALL_ENDS (default): one edge that is no colour edge keeps the whole box
    assert refine_box([12, 20, 30, 41], _mask_of(mask), (80, 60), 2) == [12, 20, 30, 41]
    monkeypatch.setattr(edge_refine, "ALL_ENDS", False)
    # each edge by itself: the cut stays, the colour edges move
    assert refine_box([12, 20, 30, 41], _mask_of(mask), (80, 60), 2) == [11, 20, 30, 40]
    # at the image border nothing is known beyond the edge: kept
    mask[:] = 0
    mask[0:20, 0:20] = 1
    assert refine_box([0, 0, 19, 19], _mask_of(mask), (80, 60), 2) == [0, 0, 20, 20]
    assert refine_box([1, 1, 19, 19], _mask_of(mask), (20, 20), 2) == [1, 1, 19, 19]


@pytest.fixture(scope="module")
def s1_frames():
    src = SimulatedTable("hands-s1", seed=1, n_frames=60)
    out = []
    for f in src:
        gt = f.meta["groundtruth"]
        out.append((f.color.copy(), f.depth.copy(), dict(zip(gt["hand_box_ids"], gt["hand_boxes"], strict=True))))
    return out


def _centre_errors(frames, **changes) -> tuple[list[float], list[list[int]]]:
    tr = HandTracker(HandTrackerConfig(auto_init=False, seed=0, **changes))
    tid, errors, boxes = None, [], []
    for rgb, depth, gt in frames:
        ests = {e.id: e for e in tr.process(rgb, depth)}
        b = gt.get(0)
        if b is None or not (b[0] > 2 and b[1] > 2 and b[2] < 638 and b[3] < 478):
            continue
        if tid is None:
            tid = tr.start_track(b)
            continue
        errors.append(centre_error(ests[tid].box, b))
        boxes.append(list(ests[tid].box))
    return errors, boxes


def test_edge_refine_acts_on_a_simulated_hand_and_off_is_the_working_box(s1_frames):
    on, boxes_on = _centre_errors(s1_frames, edge_refine=True)
    off, boxes_off = _centre_errors(s1_frames, edge_refine=False)
    assert len(on) == len(off) > 20
    # off: every edge on a working pixel (scale 2), the box's centre about 0.8 px off the ground truth's
    assert all(v % 2 == 0 for b in boxes_off for v in b)
    assert np.mean(off) > 0.5
    # on: the edges at full resolution, the centre within a few tenths of a pixel
    assert any(v % 2 for b in boxes_on for v in b)
    assert np.mean(on) < 0.5 * np.mean(off)
