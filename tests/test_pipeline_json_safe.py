"""The pipeline's mode-state conversion to JSON-able values (tracker.pipeline._json_safe)."""

from __future__ import annotations

import json
import math

import numpy as np

from tracker.geometry.pose import Pose
from tracker.pipeline import _json_safe


def test_json_safe_leaves_numpy_values_poses_and_non_finite_numbers():
    pose = Pose.from_rt(np.eye(3), np.array([0.1, 0.2, 0.3]))
    state = {"a": 1.5, "nan": math.nan, "inf": -math.inf, "f64": np.float64(2.5),
             "i64": np.int64(7), "ok": True, "none": None, "s": "x", 3: [np.float32(0.5), (1, 2.0)],
             "arr": np.array([[1.0, np.inf]]), "pose": pose, "nested": {"deep": [float("inf"), np.bool_(True)]}}
    out = _json_safe(state)
    assert out["a"] == 1.5 and out["nan"] is None and out["inf"] is None
    assert out["f64"] == 2.5 and type(out["f64"]) is float and out["i64"] == 7 and type(out["i64"]) is int
    assert out["ok"] is True and out["none"] is None and out["s"] == "x" and out["3"] == [0.5, [1, 2.0]]
    assert out["arr"] == [[1.0, None]] and out["pose"]["t"] == [0.1, 0.2, 0.3]
    assert out["nested"] == {"deep": [None, True]}
    json.dumps(out, allow_nan=False)  # raises on a value left non-finite or not JSON-able
