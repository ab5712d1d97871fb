"""HSV ranges (wrap-around, circular statistics, OpenCV conversion), Algorithm 1 detection, calibration."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from shared_data import REAL, needs_shared

from tracker.geometry.parts import PRESET_COLORS, PartSpec
from tracker.perception.color_detection import ColorDetection, ColorDetector, calibrate_range, clip_rect
from tracker.perception.hsv_range import PRESET_RANGES, HSVRange, circular_stats, preset_range, rgb_to_hsv_float


def hsv_image_rgb(h_deg: np.ndarray, s: float, v: float) -> np.ndarray:
    """RGB uint8 pixels with the given hues (degrees), saturation and value (fractions)."""
    hsv = np.stack([np.asarray(h_deg, np.float32), np.full(np.shape(h_deg), s, np.float32),
                    np.full(np.shape(h_deg), v, np.float32)], axis=-1)
    rgb = cv2.cvtColor(hsv.reshape(-1, 1, 3), cv2.COLOR_HSV2RGB).reshape(hsv.shape)
    return np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)


def test_wrapping_range_mask_and_bounds():
    r = HSVRange(350.0, 10.0, 0.3, 1.0, 0.2, 1.0)
    assert r.wraps and r.hue_width_deg == pytest.approx(20.0) and r.hue_center_deg == pytest.approx(0.0)
    b = r.opencv_bounds()
    assert len(b) == 2 and b[0][0][0] == 175 and b[0][1][0] == 179 and b[1][0][0] == 0 and b[1][1][0] == 5
    hues = np.array([[355.0, 5.0, 0.0, 359.0, 180.0, 20.0, 340.0]])
    rgb = hsv_image_rgb(hues, 0.9, 0.8)
    m = r.mask(cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV))
    assert m[0].tolist() == [255, 255, 255, 255, 0, 0, 0]
    assert r.contains(hues, 0.9, 0.8)[0].tolist() == [True, True, True, True, False, False, False]
    # saturation / value bounds
    assert r.contains(0.0, 0.1, 0.8) == np.False_ and r.contains(0.0, 0.9, 0.1) == np.False_


def test_non_wrapping_and_full_ranges():
    r = HSVRange(100.0, 140.0)
    assert not r.wraps and len(r.opencv_bounds()) == 1
    assert r.opencv_bounds()[0][0].tolist() == [50, 0, 0] and r.opencv_bounds()[0][1].tolist() == [70, 255, 255]
    full = HSVRange.from_center(0.0, 200.0, 0, 1, 0, 1)
    assert full.full_hue and full.contains(123.0, 0.5, 0.5)
    with pytest.raises(ValueError, match="fractions"):
        HSVRange(0, 10, 0, 255, 0, 1)
    with pytest.raises(ValueError, match="hue bounds"):
        HSVRange(-5, 10)
    with pytest.raises(ValueError, match="HxWx3 uint8"):
        r.mask(np.zeros((4, 4), np.uint8))


def test_opencv_round_trip_of_the_jenga_yaml_red():
    r = HSVRange.from_opencv([160, 130, 50], [180, 255, 255])
    assert r.h_lo_deg == 320 and r.h_hi_deg == 360 and r.s_lo == pytest.approx(130 / 255)
    hsv = np.array([[[170, 200, 200], [0, 200, 200], [150, 200, 200], [170, 100, 200]]], np.uint8)
    assert r.mask(hsv)[0].tolist() == [255, 255, 0, 0]
    d = r.to_dict()
    assert HSVRange.from_dict(d) == r
    with pytest.raises(ValueError, match="missing field 'h_hi_deg'"):
        HSVRange.from_dict({"h_lo_deg": 1})


def test_circular_statistics_straddling_zero():
    rng = np.random.default_rng(0)
    h = np.mod(rng.normal(0.0, 4.0, 5000), 360.0)  # hues around 0°: half near 360°
    mean, sd = circular_stats(h)
    assert min(mean, 360 - mean) < 0.5
    assert 3.5 < sd < 4.5
    assert np.std(h) > 100  # what a linear standard deviation would have given


def test_calibration_red_part_straddling_zero():
    """A red part whose hues straddle 0°/360°: the calibrated range wraps and stays narrow."""
    rng = np.random.default_rng(1)
    hues = np.mod(rng.normal(0.0, 3.0, (40, 60)), 360.0)
    vals = rng.uniform(0.55, 0.85, (40, 60))
    patch = hsv_image_rgb(hues, 0.85, 1.0).astype(np.float64) * vals[..., None]
    img = np.full((120, 160, 3), 110, np.uint8)
    img[30:70, 50:110] = patch.astype(np.uint8)
    img[0:20, 0:40] = hsv_image_rgb(np.full((20, 40), 30.0), 0.9, 0.9)  # orange distractor
    r = calibrate_range(img, (55, 35, 50, 30))
    assert r.wraps, r
    assert r.hue_width_deg < 40
    det = ColorDetector({"red": r}).detect(img)["red"]
    assert det.detected and det.score == pytest.approx(1.0)
    assert det.center == pytest.approx((79.5, 49.5), abs=1.0)
    assert det.bbox == (50, 30, 60, 40)
    # the orange distractor and the grey background stay outside the range
    m = r.mask(cv2.cvtColor(img, cv2.COLOR_RGB2HSV))
    assert m[0:20, 0:40].max() == 0 and m[100:, :].max() == 0
    assert (m[30:70, 50:110] > 0).mean() > 0.97


def test_rectangle_outside_or_empty():
    img = np.zeros((50, 60, 3), np.uint8)
    with pytest.raises(ValueError, match="outside"):
        calibrate_range(img, (100, 10, 20, 20))
    with pytest.raises(ValueError, match="outside"):
        calibrate_range(img, (-30, -30, 20, 20))
    with pytest.raises(ValueError, match="empty"):
        calibrate_range(img, (10, 10, 0, 5))
    with pytest.raises(ValueError, match="four numbers"):
        calibrate_range(img, (10, 10, 5))
    assert clip_rect((-5, 40, 20, 30), 60, 50) == (0, 40, 15, 10)
    # partly outside: clipped and calibrated on the inside part
    img[40:, :15] = (200, 30, 30)
    r = calibrate_range(img, (-5, 40, 20, 30))
    assert r.contains(rgb_to_hsv_float(np.array([[200, 30, 30]]))[0, 0], 0.85, 0.78)


def test_empty_masks_give_score_zero():
    grey = np.full((48, 64, 3), 128, np.uint8)
    dets = ColorDetector.from_parts(["red", "green", "blue"]).detect(grey)
    for name, d in dets.items():
        assert d.name == name and d.center is None and d.score == 0.0 and d.bbox is None and not d.detected
    # a blob thinner than the 4x4 opening kernel vanishes as well
    grey[10:12, 10:40] = PRESET_COLORS["red"]
    assert ColorDetector.from_parts(["red"]).detect(grey)["red"].score == 0.0
    assert ColorDetection("x").to_dict()["center"] is None


def test_score_is_largest_area_over_total():
    img = np.full((100, 100, 3), 90, np.uint8)
    img[10:30, 10:30] = PRESET_COLORS["green"]  # 20x20
    img[60:70, 60:70] = PRESET_COLORS["green"]  # 10x10
    d = ColorDetector.from_parts(["green"]).detect(img)["green"]
    a1, a2 = 19 * 19, 9 * 9  # contour areas of the pixel squares (contours run through pixel centres)
    assert d.score == pytest.approx(a1 / (a1 + a2), rel=1e-6)
    assert d.center == pytest.approx((19.5, 19.5), abs=0.01) and d.area == pytest.approx(a1)
    assert d.contour.shape[1] == 2


def test_preset_scene_shaded_cubes():
    """Five cubes of the preset colours, each with three shaded faces, on a wood-coloured table with noise."""
    rng = np.random.default_rng(4)
    img = np.empty((240, 320, 3), np.float64)
    img[:] = (150, 120, 90)
    names = ["red", "green", "blue", "yellow", "orange"]
    truth = {}
    for i, n in enumerate(names):
        x0, y0 = 20 + 60 * i, 60 + 20 * (i % 2)
        c = np.array(PRESET_COLORS[n], float)
        img[y0 : y0 + 16, x0 : x0 + 30] = c * 0.95  # top face
        img[y0 + 16 : y0 + 40, x0 : x0 + 15] = c * 0.7  # front-left face
        img[y0 + 16 : y0 + 40, x0 + 15 : x0 + 30] = c * 0.45  # front-right face (in shadow)
        truth[n] = (x0 + 14.5, y0 + 19.5)
    img += rng.normal(0, 4, img.shape)
    img = np.clip(img, 0, 255).astype(np.uint8)
    parts = [PartSpec.cube(n, n) for n in names] + [PartSpec.cube("plain", None)]
    det = ColorDetector.from_parts(parts)
    assert set(det.ranges) == set(names)
    out = det.detect(img)
    for n in names:
        assert out[n].detected, n
        assert np.hypot(*np.subtract(out[n].center, truth[n])) < 1.5, (n, out[n].center, truth[n])
        assert out[n].score > 0.95


def test_presets_do_not_overlap_between_neighbouring_hues():
    det = ColorDetector.from_parts(list(PRESET_COLORS))
    for a in PRESET_COLORS:
        h, s, v = rgb_to_hsv_float(np.array([PRESET_COLORS[a]], float))[0]
        inside = [b for b, r in det.ranges.items() if r.contains(h, s, v)]
        assert inside == [a], (a, inside)
    assert set(PRESET_RANGES) == set(PRESET_COLORS)
    with pytest.raises(ValueError, match="unknown colour"):
        preset_range("mauve")
    with pytest.raises(ValueError, match="no part has a colour"):
        ColorDetector.from_parts([PartSpec.cube("x", None)])


@needs_shared
@pytest.mark.parametrize(
    "frame,rect",
    [(1, (300, 143, 40, 10)), (1, (285, 240, 25, 8)), (1, (332, 197, 14, 8)), (1, (360, 242, 10, 6))],
)
def test_real_jenga_calibration(frame, rect):
    from tracker.sources.recording import RecordingSource

    img = RecordingSource(REAL / "jenga").read(frame).color
    r = calibrate_range(img, rect)
    m = r.mask(cv2.cvtColor(img, cv2.COLOR_RGB2HSV))
    x, y, w, h = rect
    assert (m[y : y + h, x : x + w] > 0).mean() > 0.9  # the block it was drawn on
    assert (m > 0).mean() < 0.1  # not the wall, floor or polystyrene
    d = ColorDetector({"block": r}).detect(img)["block"]
    assert d.detected
    u, v = (int(round(c)) for c in d.center)
    x0, y0, bw, bh = d.bbox
    # the detection lies on the tower (x 250-380 in this photo) and its centre pixel has the calibrated colour
    assert 245 <= x0 and x0 + bw <= 385
    hsv = rgb_to_hsv_float(img[v, u].reshape(1, 3).astype(float))[0]
    assert r.contains(hsv[0], hsv[1], hsv[2]) or m[v - 2 : v + 3, u - 2 : u + 3].any()


@needs_shared
def test_inspect_colors_cli(capsys):
    import json

    from app.cli import main

    rc = main(["inspect", "colors", str(REAL / "jenga"), "--frame", "1", "--colors", "red,yellow",
               "--calibrate", "green=285,240,25,8"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["detections"]) == {"red", "yellow", "green"}
    g = out["detections"]["green"]
    assert g["score"] > 0 and 245 <= g["center"][0] <= 385
    assert out["ranges"]["green"]["h_lo_deg"] < out["ranges"]["green"]["h_hi_deg"]
    assert main(["inspect", "colors", str(REAL / "jenga"), "--calibrate", "green=1,2,3"]) == 1
    assert "NAME=x,y,w,h" in capsys.readouterr().err


@pytest.mark.parametrize("scenario,seed,index", [("static", 2, 0), ("guess-1", 5, 150), ("learning-5", 4, 90)])
def test_simulated_frames_centres_near_projected_truth(scenario, seed, index):
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable(scenario, seed=seed)
    f = src.render(index)
    gt = f.meta["groundtruth"]
    det = ColorDetector.from_parts(src.parts).detect(f.color)
    checked = 0
    for p in src.parts:
        uv = f.intrinsics.project(gt["poses"][p.name].t.reshape(1, 3))[0]
        d = det[p.name]
        if gt["visible"][p.name] >= 0.9:
            assert d.detected, p.name
            assert np.hypot(*(np.asarray(d.center) - uv)) < 4.0, (p.name, d.center, uv)
            assert d.score > 0.9
            checked += 1
        elif gt["visible"][p.name] == 0.0:  # hidden or out of view: nothing else has its colour
            assert not d.detected, p.name
    assert checked >= 3


def test_roi_detection_equals_full_image_detection():
    rng = np.random.default_rng(9)
    img = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)  # noisy: many small blobs everywhere
    img[40:70, 50:90] = PRESET_COLORS["blue"]
    det = ColorDetector.from_parts(["blue", "red", "yellow"])
    fast = det.detect(img)
    for n, m in det.masks(img).items():
        from tracker.perception.color_detection import detect_in_mask

        full = detect_in_mask(n, m)
        assert fast[n].score == pytest.approx(full.score) and fast[n].area == pytest.approx(full.area)
        assert (fast[n].center is None) == (full.center is None)
        if full.center is not None:
            assert np.allclose(fast[n].center, full.center) and fast[n].bbox == full.bbox


def test_one_pass_range_bits_equal_per_range_masks():
    """range_bits' bit i equals HSVRange.mask of range i (wrapping, full-hue and narrow S/V ranges), its rectangles
    equal cv2.boundingRect's, and more than 8 ranges fall back to one mask per range with the same detections."""
    from tracker.perception.range_bits import range_bits, range_luts

    rng = np.random.default_rng(3)
    hsv = rng.integers(0, 256, (90, 130, 3), dtype=np.uint8)
    hsv[..., 0] %= 180
    ranges = [HSVRange(350.0, 10.0, 0.3, 1.0, 0.2, 1.0), HSVRange(0.0, 360.0, 0.9, 1.0, 0.0, 0.1),
              HSVRange(100.0, 140.0, 0.5, 0.6, 0.5, 0.7), HSVRange(359.0, 360.0, 0.0, 1.0, 0.0, 1.0),
              HSVRange(200.0, 201.0, 0.99, 1.0, 0.99, 1.0)]  # the last one: no pixel
    bits, boxes = range_bits(hsv, range_luts(ranges), len(ranges))
    for i, r in enumerate(ranges):
        m = r.mask(hsv)
        assert np.array_equal((bits >> i) & 1, (m > 0).astype(np.uint8))
        x, y, w, h = cv2.boundingRect(m)
        assert (tuple(boxes[i]) == (x, y, x + w - 1, y + h - 1)) if w else boxes[i, 2] == -1
    assert not m.any() and range_luts(ranges * 2) is None
    img = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    img[40:70, 50:90] = PRESET_COLORS["blue"]
    names = [(n, k) for n in ("blue", "red", "yellow") for k in range(3)]
    det = ColorDetector({f"{n}{k}": preset_range(PRESET_COLORS[n]) for n, k in names})
    few = ColorDetector({n: r for n, r in list(det.ranges.items())[:8]})
    many, eight = det.detect(img), few.detect(img)
    for n, d in eight.items():
        assert (d.center, d.score, d.area, d.bbox) == (many[n].center, many[n].score, many[n].area, many[n].bbox)
    assert many["blue0"].detected and many["blue0"].bbox == many["blue2"].bbox


def test_rgb_table_bits_equal_hsv_bits():
    """rgb_range_bits (one table read per RGB pixel) gives range_bits' bit image and rectangles of the image's
    cv2.cvtColor HSV, on random pixels (odd width: OpenCV's row tails too) and every 8-bit grey and primary ramp;
    the detector built on it finds what the per-range masks find."""
    from tracker.perception.range_bits import range_bits, range_luts, rgb_bits_lut, rgb_range_bits

    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (61, 257, 3), dtype=np.uint8)
    ramp = np.arange(256, dtype=np.uint8)
    img[0, :256] = ramp[:, None]
    img[1, :256, 0], img[2, :256, 1], img[3, :256, 2] = ramp, ramp, ramp
    img[20:40, 30:90] = PRESET_COLORS["red"]
    ranges = [HSVRange(350.0, 10.0, 0.3, 1.0, 0.2, 1.0), HSVRange(0.0, 360.0, 0.9, 1.0, 0.0, 0.1),
              HSVRange(100.0, 140.0, 0.5, 0.6, 0.5, 0.7), HSVRange(200.0, 201.0, 0.99, 1.0, 0.99, 1.0)]
    luts = range_luts(ranges)
    bits, boxes = rgb_range_bits(img, rgb_bits_lut(luts), len(ranges))
    ref_bits, ref_boxes = range_bits(cv2.cvtColor(img, cv2.COLOR_RGB2HSV), luts, len(ranges))
    assert np.array_equal(bits, ref_bits) and np.array_equal(boxes, ref_boxes)
    assert bits.any() and boxes[3, 2] == -1
    det = ColorDetector({n: preset_range(PRESET_COLORS[n]) for n in ("red", "blue", "yellow")})
    fast = det.detect(img)
    for n, m in det.masks(img).items():
        from tracker.perception.color_detection import detect_in_mask

        full = detect_in_mask(n, m)
        assert (fast[n].center, fast[n].area, fast[n].bbox) == (full.center, full.area, full.bbox)
    assert fast["red"].detected
