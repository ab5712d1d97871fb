"""The odometry mask's kernels (tracker/odometry/foreground.py) give exactly the numpy / OpenCV values they replace."""

import cv2
import numpy as np

from tracker.odometry.foreground import fill_large_blobs, foreground


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.float32]:
    """A 120×160 depth image (metres, float32) of a tilted table with boxes standing on it and NaN holes, a static
    mask over part of it, and the per-pixel ray dots with the table normal."""
    rng = np.random.default_rng(seed)
    h, w = 120, 160
    depth = np.full((h, w), 0.8, np.float32) + rng.normal(0, 0.002, (h, w)).astype(np.float32)
    depth += np.linspace(0, 0.1, h, dtype=np.float32)[:, None]
    for _ in range(6):  # boxes 2-15 cm above the table, some large (a hand), some small (a part)
        v, u = rng.integers(0, h - 10), rng.integers(0, w - 10)
        bh, bw = rng.integers(3, 45, size=2)
        depth[v:v + bh, u:u + bw] -= np.float32(rng.uniform(0.02, 0.15))
    depth[rng.random((h, w)) < 0.03] = np.nan
    static = np.zeros((h, w), np.uint8)
    static[10:30, 20:60] = 1
    rx = (np.arange(w, dtype=np.float32) - np.float32(80)) / np.float32(150)
    ry = (np.arange(h, dtype=np.float32) - np.float32(60)) / np.float32(150)
    n = np.array([0.0, -0.6, -0.8], np.float32)
    dots = (n[0] * rx)[None, :] + (n[1] * ry + n[2])[:, None]
    return depth, static, dots, np.float32(0.66)


def test_foreground_and_large_blob_boxes_match_numpy_and_opencv() -> None:
    lo, hi = np.float32(0.012), np.float32(0.40)
    for seed in range(5):
        depth, static, dots, offset = _scene(seed)
        with np.errstate(invalid="ignore"):
            height = depth * dots + offset
            ref = ((height > 0.012) & (height < 0.40) & (static == 0)).astype(np.uint8)
        fg = foreground(depth[::1, ::1], dots, offset, static, lo, hi)
        assert fg.any() and not fg.all()
        np.testing.assert_array_equal(fg, ref)
        n_blobs, _, stats, _ = cv2.connectedComponentsWithStats(ref, connectivity=8)
        for x, y, bw, bh, area in stats[1:n_blobs]:
            if area >= 200:
                ref[y:y + bh, x:x + bw] = 1
        n_labels, labels = cv2.connectedComponents(fg, connectivity=8, ltype=cv2.CV_32S)
        fill_large_blobs(fg, labels, n_labels, 200)
        assert (fg != foreground(depth, dots, offset, static, lo, hi)).any()  # some box was filled
        np.testing.assert_array_equal(fg, ref)


def test_foreground_reads_a_strided_view() -> None:
    depth, static, dots, offset = _scene(7)
    big = np.repeat(np.repeat(depth, 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(foreground(big[::2, ::2], dots, offset, static, np.float32(0.012), np.float32(0.4)),
                                  foreground(depth, dots, offset, static, np.float32(0.012), np.float32(0.4)))
