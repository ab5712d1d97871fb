"""``assembly-agent track`` on the external development set castle-simu (ViSP's synthetic castle, a few frames).

The recording is grey (no part colour) and has depth of the object only (no table): ``track`` must run on it as
given, must not take the castle's own floor for a table, and must stay near the exact ground truth. The bounds are
tighter than ViSP's own CI bound; benchmarks/bench_castle.py has the full figures.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from shared_data import EXTERNAL, needs_shared

from app.cli import main
from tracker.geometry.pose import Pose

CASTLE = EXTERNAL / "castle-simu"
FRAMES = 5
CASTLE_T_MAX_MM = 1.0
"""Largest translation error (mm) allowed over the first FRAMES frames: half ViSP's own CI bound (2 mm); measured
0.03–0.2 mm with the dense-depth refinement (1.3–1.6 mm before it)."""
CASTLE_R_MAX_DEG = 0.25
"""Largest rotation error (degrees, geodesic) allowed over the first FRAMES frames: ViSP's CI asserts 0.4°;
measured 0.01–0.05° with the refinement (0.16–0.25° before)."""


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """Per-frame poses written by ``track --out`` and the command's printed report."""
    out = tmp_path_factory.mktemp("castle") / "poses.jsonl"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["track", str(CASTLE), "--frames", str(FRAMES), "--out", str(out)])
    return rc, [json.loads(s) for s in out.read_text().splitlines()], buf.getvalue()


@needs_shared
def test_track_runs_on_castle_simu_without_table_or_colour(tracked):
    rc, lines, text = tracked
    assert rc == 0
    assert [d["index"] for d in lines] == list(range(FRAMES))
    for d in lines:
        assert set(d["poses"]) == {"castle"}
        pose = d["poses"]["castle"]
        assert len(pose["t"]) == 3 and len(pose["q"]) == 4
        assert abs(np.linalg.norm(pose["q"]) - 1.0) < 1e-6
    # the castle's floor is a large plane but part of the object: no table may be used
    assert "table plane: not found" in text
    assert "colour: off" in text
    assert "castle" in text and "t mean" in text


@needs_shared
def test_castle_simu_errors_are_bounded(tracked):
    _, lines, _ = tracked
    truth = {}
    for s in (CASTLE / "groundtruth.jsonl").read_text().splitlines():
        d = json.loads(s)
        truth[d["index"]] = Pose.from_dict(d["poses"]["castle"])
    t_mm, r_deg = [], []
    for d in lines:
        est, gt = Pose.from_dict(d["poses"]["castle"]), truth[d["index"]]
        t_mm.append(1000 * est.translation_error(gt))
        r_deg.append(float(np.degrees(est.rotation_error(gt))))
    assert np.all(np.isfinite(t_mm)) and np.all(np.isfinite(r_deg))
    assert max(t_mm) <= CASTLE_T_MAX_MM, t_mm
    assert max(r_deg) <= CASTLE_R_MAX_DEG, r_deg
