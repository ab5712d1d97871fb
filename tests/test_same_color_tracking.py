"""Same-colour tracking (Algorithm 2, corrected) on short drawn sequences with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.geometry.parts import PRESET_COLORS
from tracker.perception.hsv_range import preset_range
from tracker.perception.same_color_tracking import SameColorSettings, SameColorTracker

RED = np.array(PRESET_COLORS["red"], float)


def draw_cube(img: np.ndarray, cx: float, cy: float, size: int = 30) -> None:
    """A cube seen from above-front: bright top half, darker lower half, centred at (cx, cy)."""
    x0, y0 = int(round(cx - size / 2)), int(round(cy - size / 2))
    img[y0 : y0 + size // 2, x0 : x0 + size] = RED * 0.95
    img[y0 + size // 2 : y0 + size, x0 : x0 + size] = RED * 0.6


def contact_sequence(seed: int = 0, hand: bool = True):
    """Two red cubes approach each other, stay in contact (one merged blob) for 8 frames, then separate.
    A skin-coloured hand covers cube A completely on frames 2-5. Yields (rgb, {name: true centre})."""
    rng = np.random.default_rng(seed)
    xa, xb = 110.0, 250.0
    ya, yb = 200.0, 208.0
    speed = 5.0
    frames = []
    phase_contact = 0
    for t in range(40):
        if xb - xa > 30.0 and phase_contact == 0:
            xa, xb = xa + speed, xb - speed
            if xb - xa <= 30.0:
                xa, xb = (xa + xb) / 2 - 15.0, (xa + xb) / 2 + 15.0
                phase_contact = 1
        elif phase_contact and phase_contact <= 8:
            phase_contact += 1
        else:
            xa, xb = xa - speed, xb + speed
        img = np.empty((320, 400, 3), float)
        img[:] = (120, 115, 110)
        draw_cube(img, xa, ya)
        draw_cube(img, xb, yb)
        if hand and 2 <= t <= 5:
            img[150:260, int(xa) - 40 : int(xa) + 40] = (225, 175, 145)
        img += rng.normal(0, 3, img.shape)
        frames.append((np.clip(img, 0, 255).astype(np.uint8), {"A": (xa, ya), "B": (xb, yb)}))
    return frames


def run_identity(settings: SameColorSettings | None = None, seed: int = 0, hand: bool = True):
    frames = contact_sequence(seed, hand)
    tr = SameColorTracker(preset_range("red"), settings)
    _, c0 = frames[0]
    tr.init_boxes({n: (c[0] - 18, c[1] - 18, 36, 36) for n, c in c0.items()})
    correct, results = 0, []
    for rgb, truth in frames:
        dets = tr.update(rgb)
        results.append((dets, truth))
        ok = True
        for n, d in dets.items():
            if d.center is None:
                continue
            other = "B" if n == "A" else "A"
            e_self = np.hypot(*np.subtract(d.center, truth[n]))
            e_other = np.hypot(*np.subtract(d.center, truth[other]))
            ok &= bool(e_self < e_other and e_self < 15.0)
        correct += ok
    return correct / len(frames), results


def test_identities_kept_through_contact_and_hand_occlusion():
    frac, results = run_identity()
    assert frac == 1.0
    # while the hand covers A it is reported as not detected, and B stays detected
    dets, _ = results[3]
    assert dets["A"].center is None and dets["A"].score == 0.0 and dets["B"].detected
    # during contact both are detected from the k-means split, with reduced scores
    contact = [d for d, t in results if abs(t["B"][0] - t["A"][0]) <= 30.5]
    assert len(contact) >= 8
    assert all(d["A"].detected and d["B"].detected and d["A"].score <= 0.5 for d in contact)
    # after separation the centres are accurate again
    dets, truth = results[-1]
    for n in "AB":
        assert np.hypot(*np.subtract(dets[n].center, truth[n])) < 3.0
        assert dets[n].score > 0.5


def test_occluded_box_grows_and_moves_with_prediction():
    tr = SameColorTracker(preset_range("red"), SameColorSettings(growth=3.0, margin=2.0, velocity_factor=0.5))
    img = np.full((200, 200, 3), 120, np.uint8)
    draw_cube(img, 50, 50)
    tr.init_boxes({"A": (30, 30, 40, 40)})
    tr.update(img)
    box0 = tr.boxes["A"]
    assert box0 == (33, 33, 34, 34)  # the blob's 30x30 bbox plus the 2 px margin
    blank = np.full((200, 200, 3), 120, np.uint8)
    d = tr.update(blank)["A"]
    assert d.center is None and d.score == 0.0
    box1 = tr.boxes["A"]
    assert box1[2] == box0[2] + 6 and box1[3] == box0[3] + 6
    for _ in range(100):
        tr.update(blank)
    assert max(tr.boxes["A"][2:]) <= tr.settings.max_box


def test_errors_and_empty_frames():
    tr = SameColorTracker(preset_range("red"))
    with pytest.raises(RuntimeError, match="init_boxes"):
        tr.update(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ValueError, match="positive width"):
        tr.init_boxes({"A": (0, 0, 0, 5)})
    with pytest.raises(ValueError, match=r"\(x, y, w, h\)"):
        tr.init_boxes({"A": (0, 0, 5)})
    with pytest.raises(ValueError):
        SameColorTracker("red")  # type: ignore[arg-type]
    tr.init_boxes({"A": (0, 0, 5, 5), "B": (5, 5, 5, 5)})
    out = tr.update(np.zeros((10, 10, 3), np.uint8))
    assert set(out) == {"A", "B"} and all(d.score == 0.0 for d in out.values())


def test_simulated_same_colour_sequence_keeps_identities():
    """Five simulated cubes re-hued to one red (own shading kept) while the hand moves one of them."""
    import cv2

    from tracker.perception.hsv_range import rgb_to_hsv_float
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("guess-2", seed=3)
    parts = src.parts[:5]
    names = [p.name for p in parts]
    red_h = float(rgb_to_hsv_float(np.array([PRESET_COLORS["red"]], float))[0, 0])
    tr = SameColorTracker(preset_range("red"))
    n_eval = n_ok = 0
    for k, i in enumerate(range(0, 240, 4)):
        ids = src.render_clean(i)["ids"].copy()
        f = src.render(i)
        hsv = rgb_to_hsv_float(f.color)
        hsv[..., 0] = np.where((ids >= 0) & (ids < len(parts)), red_h, hsv[..., 0])
        rgb = np.clip(np.round(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB) * 255), 0, 255).astype(np.uint8)
        gt = f.meta["groundtruth"]
        centres = {n: f.intrinsics.project(gt["poses"][n].t.reshape(1, 3))[0] for n in names}
        if k == 0:
            boxes = {}
            for p in parts:
                uv = f.intrinsics.project(gt["poses"][p.name].transform_points(p.vertices()))
                boxes[p.name] = (*uv.min(axis=0), *(uv.max(axis=0) - uv.min(axis=0)))
            tr.init_boxes(boxes)
        out = tr.update(rgb)
        for n in names:
            if gt["visible"][n] < 0.5:
                continue
            n_eval += 1
            d = out[n]
            if d.detected:
                e = {m: np.hypot(*(np.asarray(d.center) - c)) for m, c in centres.items()}
                n_ok += min(e, key=e.get) == n and e[n] < 12.0
    assert n_eval > 200
    assert n_ok / n_eval > 0.9
