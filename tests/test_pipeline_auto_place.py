"""Automatic placement of untracked parts: ``AssemblyPipeline.auto_place``, the automatic mode, the snapshot's
``carried`` field and ``POST /api/parts/auto-place`` (on the simulated ``static`` table, no initial poses)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from api_client import app_client, wait_frames

from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.parts import PartSpec
from tracker.pipeline import AssemblyPipeline
from tracker.sources.simulator import SimulatedTable

CONFIG = TrackerConfig.preset("default").with_overrides(n_particles=30)
CRATE = PartSpec(name="crate", box=(0.3, 0.3, 0.3))  # a 30 cm box that is not on the table


class NoPoses(SimulatedTable):
    """The simulated table as a camera sees it: no initial poses."""

    @property
    def initial_poses(self):
        return {}


class NoPosesWithCrate(NoPoses):
    """... and a part that is not on the table."""

    @property
    def parts(self):
        return [*super().parts, CRATE]


@pytest.fixture(scope="module")
def static_frames():
    src = SimulatedTable("static", seed=3, realtime=False, n_frames=5)
    frames = list(src)
    return src.parts, src.intrinsics, frames


def _errors_mm(poses, frame) -> dict[str, float]:
    gt = frame.meta["groundtruth"]["poses"]
    return {n: 1000.0 * float(np.linalg.norm(poses[n].t - gt[n].t)) for n in gt}


def test_auto_place_places_every_cube_and_tracker_follows(static_frames):
    parts, intr, frames = static_frames
    p = AssemblyPipeline(parts, intr, mode=None, config=CONFIG)
    snap = p.process(frames[0])
    assert snap.poses == {} and p.tracker is None and snap.carried == []
    results = p.auto_place(frames[0])
    assert set(results) == {q.name for q in parts}
    for name, r in results.items():
        assert "error" not in r, (name, r)
        assert len(r["t"]) == 3 and len(r["q"]) == 4 and 0.0 <= r["residual_mm"] < 3.0
    assert max(_errors_mm(p.poses, frames[0]).values()) < 5.0
    assert p.unplaced() == [] and p.auto_place(frames[0]) == {}  # nothing left to place
    for f in frames[1:]:
        snap = p.process(f)
    assert set(snap.particles) == {q.name for q in parts}  # the tracker runs on every placed part
    assert max(_errors_mm(snap.poses, frames[-1]).values()) < 5.0
    assert not snap.errors
    d = snap.to_dict()
    assert isinstance(d["carried"], list) and d["carried"] == []


def test_part_not_found_is_reported_and_others_placed(static_frames):
    parts, intr, frames = static_frames
    p = AssemblyPipeline([*parts, CRATE], intr, mode=None, config=CONFIG)
    results = p.auto_place(frames[0])
    assert "error" in results["crate"] and "crate" in results["crate"]["error"]
    assert "crate" not in p.poses
    placed = {n for n, r in results.items() if "error" not in r}
    assert placed == {q.name for q in parts}
    assert max(_errors_mm(p.poses, frames[0]).values()) < 5.0
    with pytest.raises(ValueError, match="unknown part 'violet'"):
        p.auto_place(frames[0], ["violet"])
    # a named, tracked part is placed again; the others stay where they are
    before = {n: pose.t.copy() for n, pose in p.poses.items()}
    again = p.auto_place(frames[0], ["green"])
    assert set(again) == {"green"} and "error" not in again["green"]
    assert all(np.allclose(p.poses[n].t, before[n]) for n in before if n != "green")


def test_automatic_mode_places_parts_and_reports_the_missing_one(static_frames):
    parts, intr, frames = static_frames
    p = AssemblyPipeline([*parts, CRATE], intr, mode=None, config=CONFIG, auto_place=True, auto_place_interval_s=2.0)
    calls = []
    original = p.auto_place
    p.auto_place = lambda *a, **k: calls.append(a[0].index) or original(*a, **k)
    snaps = [p.process(f) for f in frames]
    assert calls == [0]  # frames 1..4 are within 2 s of the attempt: no new attempt
    assert set(snaps[0].poses) == {q.name for q in parts}
    assert max(_errors_mm(snaps[-1].poses, frames[-1]).values()) < 5.0
    for s in snaps:  # the missing part is reported on every frame, the frame still runs
        assert any(e.startswith("auto-place crate:") for e in s.errors), s.errors
    later = type(frames[-1])(99, frames[-1].timestamp + 2.5, frames[-1].color, frames[-1].depth, intr, {})
    p.process(later)
    assert calls == [0, 99]  # due again after the interval, only for the missing part
    # without auto_place nothing is placed by itself
    off = AssemblyPipeline(parts, intr, mode=None, config=CONFIG)
    assert off.process(frames[0]).poses == {}


def test_snapshot_carried_is_a_list(static_frames):
    parts, intr, frames = static_frames
    gt = frames[0].meta["groundtruth"]["poses"]
    p = AssemblyPipeline(parts, intr, mode=None, config=CONFIG, initial_poses=gt)
    snap = p.process(frames[0])
    assert isinstance(snap.carried, list) and all(isinstance(n, str) for n in snap.carried)
    assert set(snap.carried) <= {q.name for q in parts}
    assert snap.to_dict()["carried"] == snap.carried


@pytest.fixture()
def client(tmp_path):
    def open_source(_spec):
        return NoPosesWithCrate("static", 3, realtime=False, n_frames=200)

    # auto_place off: the endpoint places the parts
    with app_client(tmp_path, open_source, source="sim:static", max_fps=30, auto_place=False) as c:
        yield c


def test_auto_place_endpoint(client):
    wait_frames(client, 2, 30.0)
    assert client.get("/api/snapshot").json()["poses"] == {}
    r = client.post("/api/parts/auto-place")
    assert r.status_code == 200, r.text
    body = r.json()
    res = body["results"]
    assert set(res) == {"red", "green", "blue", "yellow", "orange", "crate"}
    assert res["crate"]["error"] and res["crate"]["t"] is None
    for name in ("red", "green", "blue", "yellow", "orange"):
        assert res[name]["error"] is None and len(res[name]["t"]) == 3 and res[name]["residual_mm"] < 3.0
    t0 = time.time()
    while time.time() - t0 < 20:
        snap = client.get("/api/snapshot").json()
        if len(snap["poses"]) == 5:
            break
        time.sleep(0.05)
    assert set(snap["poses"]) == {"red", "green", "blue", "yellow", "orange"}
    assert isinstance(snap["carried"], list)
    # with a body naming parts: only those
    r = client.post("/api/parts/auto-place", json={"names": ["blue"]})
    assert r.status_code == 200 and list(r.json()["results"]) == ["blue"]
    # bad bodies: a clear 4xx, and the server keeps answering
    r = client.post("/api/parts/auto-place", json={"names": ["violet"]})
    assert r.status_code == 422 and "unknown part 'violet'" in r.json()["detail"]
    r = client.post("/api/parts/auto-place", json={"names": "red"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][-1] == "names"
    r = client.post("/api/parts/auto-place", json={"parts": ["red"]})
    assert r.status_code == 422 and "not a known field" in r.json()["detail"][0]["msg"]
    r = client.post("/api/parts/auto-place", content=b"{not json", headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    assert client.get("/api/status").json()["worker"]["state"] in ("running", "starting")  # 200 frames: it loops
    assert "/api/parts/auto-place" in client.get("/openapi.json").json()["paths"]
