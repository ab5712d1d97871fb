"""Hand tracking (tracker/hands): skin model, metrics, resampling, particle filter, Kalman reference, track start and
termination, the ``hands`` command and its bad input. Short seeded simulator sequences (training seed 3)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from shared_data import EXTERNAL, needs_shared

from app.cli import main
from tracker.hands.metrics import centre_error, colour_f_score, dice, frame_metrics
from tracker.hands.particle_filter import systematic_resample
from tracker.hands.skin_model import SkinModel, crcb
from tracker.hands.tracker import HandTracker, HandTrackerConfig
from tracker.sources.recording import RecordingWriter
from tracker.sources.simulator import SimulatedTable

N_FRAMES = 70


@pytest.fixture(scope="module")
def s1() -> tuple[list[np.ndarray], list[dict]]:
    src = SimulatedTable("hands-s1", seed=3, n_frames=N_FRAMES)
    frames, boxes = [], []
    for f in src:
        frames.append(f.color.copy())
        gt = f.meta["groundtruth"]
        boxes.append(dict(zip(gt["hand_box_ids"], gt["hand_boxes"], strict=True)))
    return frames, boxes


def _inside(b: list[int]) -> bool:
    return b[0] > 2 and b[1] > 2 and b[2] < 638 and b[3] < 478


def _track_gt_start(frames, boxes, method: str, n_particles: int = 30) -> list[float]:
    tr = HandTracker(HandTrackerConfig(method=method, n_particles=n_particles, auto_init=False, seed=1))
    tid = None
    scores = []
    for rgb, gt in zip(frames, boxes, strict=True):
        ests = {e.id: e for e in tr.process(rgb)}
        b = gt.get(0)
        if b is None or not _inside(b):
            continue
        if tid is None:
            tid = tr.start_track(b)
            continue
        scores.append(dice(ests[tid].box, b) if tid in ests else 0.0)
    return scores


@needs_shared
def test_skin_model_beats_the_box_rule_on_the_labelled_test_half():
    with np.load(EXTERNAL / "skin" / "skin_nonskin.npz") as z:
        bgr, label = z["bgr"], z["label"]
    test = np.random.default_rng(0).permutation(len(label))[122528:]  # the README's split; the model saw the rest
    x = crcb(bgr[test][:, ::-1].reshape(-1, 1, 3)).reshape(-1, 2)
    y = label[test] == 1
    ours = np.mean(SkinModel.load().with_threshold(0.0).classify(x).astype(bool) == y)
    box = (x[:, 0] >= 133) & (x[:, 0] <= 173) & (x[:, 1] >= 77) & (x[:, 1] <= 127)
    assert ours > np.mean(box == y)
    assert ours > 0.995


def test_skin_model_file_round_trip_and_bad_file(tmp_path):
    m = SkinModel.load()
    m.save(tmp_path / "m.json")
    assert np.array_equal(SkinModel.load(tmp_path / "m.json").lut, m.lut)
    (tmp_path / "bad.json").write_text('{"skin": 3}')
    with pytest.raises(ValueError, match="bad.json"):
        SkinModel.load(tmp_path / "bad.json")


def test_session_background_separates_the_hand_from_the_table(s1):
    frames, boxes = s1
    model = SkinModel.load().with_threshold(-2.0)
    session = model.with_background(frames[0])
    src = SimulatedTable("hands-s1", seed=3)
    skin = src.render(40).meta["groundtruth"]["skin_mask"] > 0

    def f_score(m: SkinModel) -> float:
        b = m.mask(frames[40]).astype(bool)
        return 2 * np.count_nonzero(b & skin) / (np.count_nonzero(b) + np.count_nonzero(skin))

    assert f_score(session) > 0.9
    assert f_score(session) >= f_score(model)


def test_metrics_on_known_boxes():
    assert centre_error([0, 0, 10, 10], [3, 4, 13, 14]) == pytest.approx(5.0)
    assert dice([0, 0, 10, 10], [5, 0, 15, 10]) == pytest.approx(0.5)
    mask = np.zeros((20, 20), np.uint8)
    mask[0:10, 0:5] = 1
    m = frame_metrics([0, 0, 10, 10], [0, 0, 5, 10], mask)
    assert m["F_c"] == pytest.approx(1.0) and m["F_b"] == pytest.approx(2 * 50 / 150)
    assert colour_f_score([10, 10, 20, 20], [12, 12, 20, 20], mask) == 1.0  # both sets empty


def test_systematic_resampling_follows_the_weights():
    rng = np.random.default_rng(0)
    assert np.all(systematic_resample(np.array([0.0, 0.0, 1.0, 0.0]), rng) == 2)
    idx = systematic_resample(np.full(8, 1 / 8), rng)
    assert sorted(idx.tolist()) == list(range(8))
    counts = np.bincount(systematic_resample(np.array([0.5, 0.25, 0.25, 0.0]), rng), minlength=4)
    assert counts.tolist() == [2, 1, 1, 0]


def test_particle_filter_follows_the_hand_on_s1(s1):
    scores = _track_gt_start(*s1, method="pf")
    assert len(scores) > 30
    assert np.mean(scores) > 0.9


def test_kalman_reference_follows_the_hand_on_s1(s1):
    scores = _track_gt_start(*s1, method="kalman")
    assert len(scores) > 30
    assert np.mean(scores) > 0.8


def test_automatic_start_and_termination(s1):
    frames, boxes = s1
    tr = HandTracker(HandTrackerConfig(seed=0))
    first_gt = next(i for i, b in enumerate(boxes) if b)
    started = None
    for i, rgb in enumerate(frames[:50]):
        ests = tr.process(rgb)
        if ests and started is None:
            started = i
        if started is not None and i > started + 5:
            assert len(ests) == 1 and ests[0].id == 1
            assert dice(ests[0].box, boxes[i][0]) > 0.7
    assert started is not None and started - first_gt <= 8
    # the hand vanishes: the empty table is shown; the track ends after n_lost frames without skin in its box
    alive = [len(tr.process(frames[0])) for _ in range(14)]
    assert alive[0] == 1 and alive[-1] == 0
    assert sum(alive) <= 11


def test_duplicate_tracks_end_the_younger_one(s1):
    frames, boxes = s1
    i0 = next(i for i, b in enumerate(boxes) if b.get(0) and _inside(b[0]))
    tr = HandTracker(HandTrackerConfig(auto_init=False, seed=0))
    tr.process(frames[i0])
    a = tr.start_track(boxes[i0][0])
    b = tr.start_track(boxes[i0][0])
    ids = [{e.id for e in tr.process(rgb)} for rgb in frames[i0 + 1 : i0 + 16]]
    assert ids[0] == {a, b} and ids[-1] == {a}


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="method"):
        HandTrackerConfig(method="magic")
    with pytest.raises(ValueError, match="particle"):
        HandTrackerConfig(n_particles=0)
    with pytest.raises(ValueError, match="uint8"):
        HandTracker().process(np.zeros((10, 10), np.uint8))


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("hands") / "rec"
    src = SimulatedTable("hands-s1", seed=3, n_frames=40)
    with RecordingWriter(root, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as w:
        for f in src:
            w.write(f, groundtruth=f.meta["groundtruth"])
    return root


def test_hands_command_writes_one_json_line_per_frame(recording, tmp_path, capsys):
    out = tmp_path / "hands.jsonl"
    assert main(["hands", str(recording), "--out", str(out), "--particles", "20"]) == 0
    lines = [json.loads(s) for s in out.read_text().splitlines()]
    assert [ln["index"] for ln in lines] == list(range(40))
    assert all(set(ln) == {"index", "t", "hands"} for ln in lines)
    assert lines[1]["t"] == pytest.approx(1 / 30, abs=1e-6)
    hands = [h for ln in lines for h in ln["hands"]]
    assert hands and {h["id"] for h in hands} == {1}
    for h in hands:
        assert set(h) == {"id", "box", "score"} and len(h["box"]) == 4 and 0.0 <= h["score"] <= 1.0
        assert h["box"][0] < h["box"][2] and h["box"][1] < h["box"][3]
    gt = {json.loads(s)["index"]: json.loads(s)["hand_boxes"] for s in (recording / "groundtruth.jsonl").open()}
    last = lines[-1]["hands"][0]["box"]
    assert dice(last, gt[39][0]) > 0.7
    assert "tracked 40 frames" in capsys.readouterr().out


def test_hand_commands_run_opencv_on_one_thread(recording, tmp_path, monkeypatch):
    """`hands` and `evaluate hands` time the tracker on one core, as the server's hand process does: OpenCV's
    worker threads would escape the thread CPU time of Experiment 1's runtime table."""
    import tracker.evaluation.hands as evaluation

    seen: list[int] = []

    def fake_experiment(out, seeds, runs, n_frames):
        seen.append(cv2.getNumThreads())
        return {"hands-s1": {}}

    monkeypatch.setattr(evaluation, "experiment_1", fake_experiment)
    before = cv2.getNumThreads()
    try:
        cv2.setNumThreads(4)
        assert main(["evaluate", "hands", "--out", str(tmp_path / "e"), "--seeds", "100", "--runs", "1"]) == 0
        assert seen == [1]
        cv2.setNumThreads(4)
        out = tmp_path / "h.jsonl"
        assert main(["hands", str(recording), "--out", str(out), "--frames", "2"]) == 0
        assert cv2.getNumThreads() == 1 and len(out.read_text().splitlines()) == 2
    finally:
        cv2.setNumThreads(before)


def test_hands_command_bad_input(recording, tmp_path, capsys):
    assert main(["hands", str(tmp_path / "missing"), "--out", str(tmp_path / "x.jsonl")]) == 1
    assert "missing" in capsys.readouterr().err
    bad = tmp_path / "bad"
    import shutil

    shutil.copytree(recording, bad)
    (bad / "color" / "000020.png").write_bytes(b"not a png")
    out = tmp_path / "bad.jsonl"
    assert main(["hands", str(bad), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "000020" in err and "1 frame(s) could not be read" in err
    indices = [json.loads(s)["index"] for s in out.read_text().splitlines()]
    assert indices == [i for i in range(40) if i != 20]
    assert main(["hands", str(recording), "--out", str(out), "--particles", "0"]) == 1


def test_colour_conversion_matches_opencv():
    rgb = np.array([[[200, 150, 120], [10, 20, 30]]], np.uint8)
    ycc = cv2.cvtColor(rgb, cv2.COLOR_RGB2YCrCb)
    assert np.array_equal(crcb(rgb), ycc[..., 1:])


def test_contact_monitor_touching_holding_and_release():
    from tracker.hands.contact import ContactMonitor, contact_test

    hand = np.zeros((60, 60), bool)
    hand[10:30, 10:30] = True
    part = np.zeros((60, 60), bool)
    part[31:45, 12:28] = True  # 1 px gap: within r_touch = 3 px
    far = np.zeros((60, 60), bool)
    far[50:58, 50:58] = True
    assert contact_test(hand, part) and not contact_test(hand, far)
    depth = np.full((60, 60), 0.70)
    part_depth = np.full((60, 60), 0.80)
    assert not contact_test(hand, part, depth, part_depth)  # 10 cm apart in depth: the hand is above it
    mon = ContactMonitor()
    first = mon.update({1: hand}, {"red": part, "blue": far}, {"red": np.zeros(3), "blue": np.zeros(3)})
    assert first == {}  # needs 2 of the last 3 frames
    second = mon.update({1: hand}, {"red": part, "blue": far}, {"red": np.zeros(3), "blue": np.zeros(3)})
    assert second == {(1, "red"): "touching"} and mon.touched_parts() == {"red"}
    moved = mon.update({1: hand}, {"red": part, "blue": far}, {"red": np.array([0.02, 0, 0]), "blue": np.zeros(3)})
    assert moved == {(1, "red"): "holding"}
    states = [mon.update({}, {"red": part, "blue": far}) for _ in range(5)]
    assert states[3] == {(1, "red"): "holding"} and states[4] == {}  # released after n_off = 5 failing frames


def test_hand_masks_are_skin_inside_the_track_box(s1):
    frames, boxes = s1
    i0 = next(i for i, b in enumerate(boxes) if b.get(0) and _inside(b[0]))
    tr = HandTracker(HandTrackerConfig(auto_init=False, seed=0))
    tr.process(frames[i0])
    tid = tr.start_track(boxes[i0][0])
    for rgb in frames[i0 + 1 : i0 + 6]:
        est = tr.process(rgb)[0]
    m = tr.hand_masks()[tid]
    u0, v0, u1, v1 = est.box
    assert m.shape == (480, 640) and m.sum() > 500
    assert not m[:v0].any() and not m[v1:].any() and not m[:, :u0].any() and not m[:, u1:].any()
    skin = SimulatedTable("hands-s1", seed=3).render(i0 + 5).meta["groundtruth"]["skin_mask"] > 0
    assert np.count_nonzero(m & skin) > 0.8 * np.count_nonzero(m)


def test_gmm_fit_uses_no_more_components_than_distinct_colours():
    """A uniform frame has one colour: the fit gives one component (and k-means does not warn of fewer clusters);
    a varied sample keeps the asked-for four."""
    import warnings

    from tracker.hands.skin_model import Gmm2D

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        one = Gmm2D.fit(np.tile([[140.0, 110.0]], (500, 1)), 4)
    assert len(one.weights) == 1 and np.allclose(one.means, [[140.0, 110.0]])
    varied = Gmm2D.fit(np.random.default_rng(0).normal([140.0, 110.0], 8.0, (500, 2)), 4)
    assert len(varied.weights) == 4


def test_palm_box_without_specks_drops_small_pieces_of_the_palm_mask():
    from tracker.evaluation.hands import palm_box_without_specks

    m = np.zeros((60, 80), np.uint8)
    m[10:30, 20:40] = 1  # hand 0's palm
    m[45, 70] = 1  # a single palm pixel peeking past the sleeve
    m[5:9, 50:60] = 2  # hand 1
    assert palm_box_without_specks(m, 0) == [20, 10, 40, 30]  # end-exclusive, the speck left out
    assert palm_box_without_specks(m, 0, min_px=1) == [20, 10, 71, 46]  # the ground-truth box reaches it
    assert palm_box_without_specks(m, 1) == [50, 5, 60, 9]
    assert palm_box_without_specks(m, 2) is None
