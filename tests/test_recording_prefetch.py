"""The recording source's background decoding of the next frames (tracker/sources/prefetch.py)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from tracker.sources.base import SourceError
from tracker.sources.prefetch import DecodePrefetcher
from tracker.sources.recording import RecordingSource, RecordingWriter
from tracker.sources.simulator import SimulatedTable


def _recording(path, n: int = 6):
    src = SimulatedTable("static", seed=1, n_frames=n)
    with RecordingWriter(path, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as w:
        for i in range(n):
            f = src.render(i)
            w.write(f, f.meta["groundtruth"])
    return path


def test_prefetched_frames_equal_frames_decoded_on_demand(tmp_path):
    rec = _recording(tmp_path / "rec")
    ahead, plain = RecordingSource(rec), RecordingSource(rec, prefetch=0)
    for i in range(len(plain)):
        a, b = ahead.read(i), plain.read(i)
        assert a.index == b.index and np.array_equal(a.color, b.color)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        if i + 1 < len(plain):
            assert i + 1 in ahead._prefetch.pending  # the next one is being decoded already
    assert plain._prefetch.pending == []
    ahead.close()
    assert ahead.read(2).index == plain.read(2).index  # reads still work after close, decoding on demand


def test_a_frame_corrupt_when_prefetched_gives_the_reader_its_own_error_or_its_repaired_image(tmp_path):
    rec = _recording(tmp_path / "rec")
    good = (rec / "color" / "000003.png").read_bytes()
    (rec / "color" / "000003.png").write_bytes(b"not a png")
    src = RecordingSource(rec)
    src.read(2)  # prefetches 3 (corrupt) and 4
    src._prefetch._pending[3].exception(timeout=10)  # the prefetch has failed
    with pytest.raises(SourceError, match="000003.png"):
        src.read(3)
    src.read(1)  # prefetches 2 and 3 again, 3 still corrupt
    src._prefetch._pending[3].exception(timeout=10)
    (rec / "color" / "000003.png").write_bytes(good)  # repaired after the failed prefetch
    assert src.read(3).index == 3
    assert np.array_equal(src.read(3).color, RecordingSource(rec, prefetch=0).read(3).color)


def test_prefetcher_wraps_when_looping_and_drops_what_a_jump_leaves_behind():
    calls: list[int] = []
    lock = threading.Lock()

    def decode(i: int) -> int:
        with lock:
            calls.append(i)
        return 10 * i

    pre = DecodePrefetcher(decode, size=5, depth=2, wrap=True)
    assert pre.get(4) == 40 and sorted(pre.pending) == [0, 1]
    assert pre.get(0) == 0 and sorted(pre.pending) == [1, 2]
    assert pre.get(3) == 30 and sorted(pre.pending) == [0, 4]  # 1 and 2 dropped
    end = DecodePrefetcher(decode, size=5, depth=2, wrap=False)
    assert end.get(4) == 40 and end.pending == []
    with pytest.raises(ValueError, match="depth"):
        DecodePrefetcher(decode, size=5, depth=-1)
    pre.close()
    end.close()


def test_the_server_opens_recordings_without_decoding_ahead(tmp_path):
    """The server's frame reader produces each frame just in time in its own thread and skips stale ones; its
    recordings are opened with prefetch 0 (decoding ahead would decode frames it then skips), the commands' with 2."""
    from app.state import open_source_spec
    from tracker.sources.registry import open_source

    rec = _recording(tmp_path / "rec", n=3)
    served = open_source_spec(f"recording:{rec}")
    served.read(0)
    assert served._prefetch.pending == []
    plain = open_source(str(rec))
    plain.read(0)
    assert sorted(plain._prefetch.pending) == [1, 2]
    assert open_source_spec("sim:static").n_frames > 0  # the option does not reach other sources
    plain.close()


def test_colour_analysis_runs_as_frames_are_decoded_ahead_and_equals_running_it_at_the_read(tmp_path):
    """``analyse_colour(fn)``: each frame comes with ``(fn, fn(colour))``; for a frame decoded ahead it was computed
    in the prefetch thread, for one decoded before the call (or with another fn) at the read; the track session
    takes a colour detector's result from there, and its poses equal those of a session that detects itself."""
    from app.commands.track import TrackSession
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.perception.color_detection import ColorDetector

    rec = _recording(tmp_path / "rec")
    src = RecordingSource(rec)
    first = src.read(0)  # decodes 1 and 2 ahead, before any analysis is set
    assert "colour_analysis" not in first.meta
    for q in (1, 2):
        src._prefetch._pending[q].result(timeout=30)  # decoded without analysis
    where: list[str] = []
    detector = ColorDetector.from_parts([p for p in src.parts if p.color is not None])

    def detect(rgb):
        where.append(threading.current_thread().name)
        return detector.detect(rgb)

    src.analyse_colour(detect)
    frames = [src.read(i) for i in range(1, len(src))]
    assert all(f.meta["colour_analysis"][0] is detect for f in frames)
    # frames 1 and 2: decoded before the call, analysed at the read; the others as they were decoded ahead
    assert len(where) == len(frames) and where.count("MainThread") == 2
    assert all(w == "MainThread" or w.startswith("recording-decode") for w in where)
    for f in frames:
        want = detector.detect(f.color)
        got = f.meta["colour_analysis"][1]
        assert set(got) == set(want) and all(np.array_equal(got[n].center, want[n].center) for n in want)
    src.close()

    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50)
    plain_src, ahead_src = RecordingSource(rec, prefetch=0), RecordingSource(rec)
    plain = TrackSession(plain_src.parts, plain_src.intrinsics, plain_src.initial_poses, cfg, seed=0)
    ahead = TrackSession(ahead_src.parts, ahead_src.intrinsics, ahead_src.initial_poses, cfg, seed=0)
    ahead_src.analyse_colour(ahead.detector.detect)
    for i in range(len(plain_src)):
        a, b = plain.step(plain_src.read(i))[0], ahead.step(ahead_src.read(i))[0]
        for name, pose in a.poses.items():
            assert np.array_equal(pose.t, b.poses[name].t) and np.array_equal(pose.q, b.poses[name].q)
    ahead_src.close()
