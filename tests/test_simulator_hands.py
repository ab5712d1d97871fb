"""The hand-tracking scenarios of the simulator (hands-s1…s3): palm boxes, skin masks, skin colours, recording."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from shared_data import needs_shared

from tracker.sources.recording import RecordingSource, RecordingWriter
from tracker.sources.simulator import SimulatedTable
from tracker.sources.simulator.skin_tones import skin_source

FRAMES = (30, 90, 150, 210, 270)


@pytest.fixture(scope="module")
def rendered() -> dict[str, list]:
    out = {}
    for name in ("hands-s1", "hands-s2", "hands-s3"):
        src = SimulatedTable(name, seed=2)
        out[name] = [src.render(i) for i in FRAMES]
    return out


def _tight(mask: np.ndarray) -> list[int]:
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return [int(cols[0]), int(rows[0]), int(cols[-1] + 1), int(rows[-1] + 1)]


def test_hand_scenarios_last_at_least_300_frames():
    for name in ("hands-s1", "hands-s2", "hands-s3"):
        assert SimulatedTable(name, seed=5).n_frames >= 300


def test_palm_boxes_are_the_tight_boxes_of_the_palm_skin(rendered):
    for frames in rendered.values():
        for f in frames:
            gt = f.meta["groundtruth"]
            skin = gt["skin_mask"]
            assert skin.shape == (480, 640) and skin.dtype == np.uint8
            assert len(gt["hand_boxes"]) == len(gt["hand_box_ids"]) >= 1
            for box, k in zip(gt["hand_boxes"], gt["hand_box_ids"], strict=True):
                assert box == _tight(skin == k + 1)
                # forearm excluded: the legacy whole-hand box is larger (it includes the arm to the border)
                hb = gt["hand_box"]
                assert hb[3] > box[3] and (hb[2] - hb[0]) * (hb[3] - hb[1]) > (box[2] - box[0]) * (box[3] - box[1])


def test_sleeves_and_bare_forearms(rendered):
    assert all((f.meta["groundtruth"]["skin_mask"] >= 128).sum() == 0 for f in rendered["hands-s1"])
    assert all((f.meta["groundtruth"]["skin_mask"] >= 128).sum() > 500 for f in rendered["hands-s3"])


def test_two_hands_overlap_in_s2():
    src = SimulatedTable("hands-s2", seed=2)
    two = overlap = 0
    for i in range(20, src.n_frames - 30, 12):
        boxes = src.render(i).meta["groundtruth"]["hand_boxes"]
        if len(boxes) == 2:
            two += 1
            a, b = boxes
            if min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1]):
                overlap += 1
    assert two >= 20 and overlap >= 2


def test_motion_blur_only_in_s3_changes_the_hand_pixels():
    src = SimulatedTable("hands-s3", seed=2)
    sharp = SimulatedTable("hands-s1", seed=2)
    # a blurred image has weaker gradients on the hand than the sharp rendering at comparable motion
    def grad(frame) -> float:
        g = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY).astype(np.float32)
        m = frame.meta["groundtruth"]["skin_mask"] > 0
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0)
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1)
        return float(np.hypot(gx, gy)[cv2.dilate(m.astype(np.uint8), np.ones((5, 5))) > 0].mean())
    blurred = np.mean([grad(src.render(i)) for i in (60, 120, 180)])
    crisp = np.mean([grad(sharp.render(i)) for i in (60, 120, 180)])
    assert blurred < crisp


@needs_shared
def test_skin_colours_come_from_the_real_skin_data(rendered):
    assert skin_source() == "uci-skin"
    for frames in rendered.values():
        f = frames[2]
        palm = f.meta["groundtruth"]["skin_mask"] == 1
        ycrcb = cv2.cvtColor(f.color, cv2.COLOR_RGB2YCrCb)[palm]
        cr, cb = ycrcb[:, 1].astype(int), ycrcb[:, 2].astype(int)
        # the classic skin chrominance box holds for most palm pixels
        assert np.mean((cr >= 133) & (cr <= 173) & (cb >= 77) & (cb <= 127)) > 0.8


def test_same_seed_same_frames_and_recording_keeps_masks(tmp_path):
    a = SimulatedTable("hands-s2", seed=7).render(100)
    b = SimulatedTable("hands-s2", seed=7).render(100)
    assert np.array_equal(a.color, b.color)
    assert a.meta["groundtruth"]["hand_boxes"] == b.meta["groundtruth"]["hand_boxes"]
    src = SimulatedTable("hands-s2", seed=7, n_frames=2)
    with RecordingWriter(tmp_path / "rec", src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as w:
        for f in src:
            w.write(f, groundtruth=f.meta["groundtruth"])
    line = json.loads((tmp_path / "rec" / "groundtruth.jsonl").read_text().splitlines()[1])
    assert line["skin_mask"] == "skin_mask/000001.png"
    rec = RecordingSource(tmp_path / "rec")
    gt = rec.groundtruth_record(1)
    mask = cv2.imread(str(tmp_path / "rec" / gt["skin_mask"]), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(mask, src.render(1).meta["groundtruth"]["skin_mask"])
    assert gt["hand_boxes"] == src.render(1).meta["groundtruth"]["hand_boxes"]


def test_the_builtin_skin_tones_warn_once(monkeypatch):
    """Without the shared skin data the hands are coloured from the built-in tones, and the first draw says so (a
    worktree without ``../shared`` otherwise renders other hands than the main checkout, silently)."""
    import warnings

    from tracker.sources.simulator import skin_tones

    monkeypatch.setattr(skin_tones, "_skin_rgb", lambda: None)
    skin_tones._warn_builtin.cache_clear()
    rng = np.random.default_rng(0)
    with pytest.warns(UserWarning, match="built-in skin tones"):
        tone = skin_tones.draw_skin_tone(rng)
    assert tone.shape == (3,) and skin_tones.skin_source() == "builtin"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        skin_tones.draw_skin_tone(rng)  # once per process
    skin_tones._warn_builtin.cache_clear()


def test_bright_tones_keep_their_hue(monkeypatch):
    """A tone brighter than 255·SHADE in a channel is scaled down as a whole, not clipped per channel: the albedo
    keeps the tone's channel ratios (clipping the red channel rendered bright skin pale and yellow)."""
    from tracker.sources.simulator import skin_tones

    for tone in ((249.0, 196.0, 178.0), (120.0, 80.0, 70.0)):
        monkeypatch.setattr(skin_tones, "draw_skin_tone", lambda rng, t=tone: np.array(t))
        palm = np.array(skin_tones.hand_albedos(np.random.default_rng(0))[0])
        assert palm.max() <= 255.0
        assert np.allclose(palm / palm.max(), np.array(tone) / max(tone))
        if max(tone) < 255.0 * skin_tones.SHADE:
            assert np.allclose(palm, np.array(tone) / skin_tones.SHADE)


@needs_shared
def test_a_bright_hand_is_rendered_near_its_drawn_tone(monkeypatch):
    """Tuning seed 2 of hands-s3 draws a bright tone; its palm pixels are rendered near the tone's chrominance."""
    from tracker.sources.simulator import skin_tones

    drawn = []
    real = skin_tones.draw_skin_tone
    monkeypatch.setattr(skin_tones, "draw_skin_tone", lambda rng: drawn.append(real(rng)) or drawn[-1])
    f = SimulatedTable("hands-s3", seed=2, n_frames=40).render(30)
    tone = cv2.cvtColor(np.uint8([[drawn[0]]]), cv2.COLOR_RGB2YCrCb)[0, 0, 1:].astype(int)
    palm = f.meta["groundtruth"]["skin_mask"] == 1
    crcb = np.median(cv2.cvtColor(f.color, cv2.COLOR_RGB2YCrCb)[palm][:, 1:], axis=0)
    assert drawn[0].max() > 255 * skin_tones.SHADE  # a tone the per-channel clip changed
    assert np.abs(crcb - tone).max() <= 6
