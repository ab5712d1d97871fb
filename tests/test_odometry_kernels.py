"""Odometry kernels made faster give exactly the values of what they replace: the mask's foreground test, blob boxes and
enlargement to full size (tracker/odometry/foreground.py) those of numpy / OpenCV, the pyramid's 2x2 depth and mask
halving (rgbd_pyramid._half_depth_mask) those of its rules written out in plain Python, its first grey level those of
OpenCV's luminance, float32 image and area resize, a keyframe's points and normals
(keyframe.points_and_normals) those of Intrinsics.backproject and the numpy normals it replaced, se3.motion_size on
Python floats the numpy form's."""

import cv2
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.odometry.foreground import enlarge_twice, fill_large_blobs, foreground
from tracker.odometry.keyframe import points_and_normals
from tracker.odometry.rgbd_pyramid import MAX_BLOCK_SPREAD, _half_depth_mask, build_pyramid


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.float32, tuple]:
    """A 120×160 depth image (metres, float32) of a tilted table with boxes standing on it and NaN holes, a static
    mask over part of it, the per-pixel ray dots with the table normal (numpy's form) and the rays and normal they are
    made of."""
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
    return depth, static, dots, np.float32(0.66), (rx, ry, n)


def test_foreground_and_large_blob_boxes_match_numpy_and_opencv() -> None:
    lo, hi = np.float32(0.012), np.float32(0.40)
    for seed in range(5):
        depth, static, dots, offset, rays = _scene(seed)
        with np.errstate(invalid="ignore"):
            height = depth * dots + offset
            ref = ((height > 0.012) & (height < 0.40) & (static == 0)).astype(np.uint8)
        fg = foreground(depth[::1, ::1], *rays, offset, static, lo, hi)
        assert fg.any() and not fg.all()
        np.testing.assert_array_equal(fg, ref)
        n_blobs, _, stats, _ = cv2.connectedComponentsWithStats(ref, connectivity=8)
        for x, y, bw, bh, area in stats[1:n_blobs]:
            if area >= 200:
                ref[y:y + bh, x:x + bw] = 1
        n_labels, labels = cv2.connectedComponents(fg, connectivity=8, ltype=cv2.CV_32S)
        fill_large_blobs(fg, labels, n_labels, 200)
        assert (fg != foreground(depth, *rays, offset, static, lo, hi)).any()  # some box was filled
        np.testing.assert_array_equal(fg, ref)


def test_foreground_reads_a_strided_view() -> None:
    depth, static, _, offset, rays = _scene(7)
    big = np.repeat(np.repeat(depth, 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(foreground(big[::2, ::2], *rays, offset, static, np.float32(0.012), np.float32(0.4)),
                                  foreground(depth, *rays, offset, static, np.float32(0.012), np.float32(0.4)))


def test_enlarge_twice_matches_a_nearest_resize_padded() -> None:
    """The half-resolution exclusion mask enlarged to the frame: ``cv2.resize`` nearest to twice its size, a last odd
    row or column False (the code it replaced), for even and odd frame sizes."""
    rng = np.random.default_rng(4)
    for h, w in [(480, 640), (481, 640), (480, 641), (7, 9), (2, 2), (3, 3), (1, 5)]:
        small = rng.random((h // 2, w // 2)) < 0.3
        ref = np.zeros((h, w), bool)
        if small.size:
            big = cv2.resize(small.view(np.uint8), (2 * (w // 2), 2 * (h // 2)), interpolation=cv2.INTER_NEAREST)
            ref[: 2 * (h // 2), : 2 * (w // 2)] = big.reshape(2 * (h // 2), 2 * (w // 2)).view(bool)
        got = enlarge_twice(small, h, w)
        assert got.dtype == np.bool_ and got.shape == (h, w)
        np.testing.assert_array_equal(got, ref)


def test_pyramid_first_grey_level_matches_opencvs_luminance_and_area_resize() -> None:
    """Level 1's grey, made from the 8-bit luminance directly, equals OpenCV's luminance as float32 halved by an area
    resize (the form it replaced, which made the full-size float32 image first); the coarser levels follow it."""
    rng = np.random.default_rng(6)
    for h, w in [(480, 640), (121, 161), (6, 4), (2, 2)]:
        rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        rgb[: h // 2, : w // 2] = rng.integers(0, 256, 3, dtype=np.uint8)  # a flat patch, its blocks alike
        depth = np.full((h, w), 0.8, np.float32)
        levels = min(3, int(np.log2(min(h, w))) + 1)
        pyr = build_pyramid(rgb, depth, Intrinsics.default(w, h), levels, None, first_level=1)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
        assert pyr[0] is None
        for lv in range(1, levels):
            ph, pw = gray.shape
            gray = cv2.resize(gray[: ph // 2 * 2, : pw // 2 * 2], (pw // 2, ph // 2), interpolation=cv2.INTER_AREA)
            assert pyr[lv].gray.dtype == np.float32
            np.testing.assert_array_equal(pyr[lv].gray, gray)


def _half_reference(depth: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The block rules one block at a time: NaN unless all four depths are finite and > 0 and their spread is at
    most MAX_BLOCK_SPREAD of their mean (float32 sum, times 0.25 in float64); a block masked when any pixel is."""
    h, w = depth.shape[0] // 2, depth.shape[1] // 2
    out = np.full((h, w), np.nan, np.float32)
    m = np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            blk = depth[2 * i:2 * i + 2, 2 * j:2 * j + 2].ravel()
            m[i, j] = mask[2 * i:2 * i + 2, 2 * j:2 * j + 2].any()
            if not (np.all(blk > 0) and np.all(np.isfinite(blk))):
                continue
            mean = float(((blk[0] + blk[1]) + blk[2]) + blk[3]) * 0.25
            if float(blk.max() - blk.min()) <= MAX_BLOCK_SPREAD * mean:
                out[i, j] = mean
    return out, m


def test_half_depth_mask_keeps_the_block_rules() -> None:
    rng = np.random.default_rng(3)
    values = np.array([0.5, 0.504, 0.51, 0.6, 1.0, 1.03, 0.0, -1.0, np.nan, np.inf], np.float32)
    for _ in range(5):
        depth = rng.choice(values, size=(24, 34), p=[0.2, 0.2, 0.1, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05, 0.05])
        depth[:8, :8] = 0.7  # whole valid blocks
        mask = rng.random(depth.shape) < 0.08
        out, m = _half_depth_mask(depth, mask, MAX_BLOCK_SPREAD)
        ref, ref_m = _half_reference(depth, mask)
        assert np.isfinite(out).any() and np.isnan(out).any() and m.any()
        np.testing.assert_array_equal(out, ref)
        np.testing.assert_array_equal(m, ref_m)


def depth_normals(points: np.ndarray) -> np.ndarray:
    """The numpy code keyframe.points_and_normals replaced (the reference): unit normals (H×W×3, NaN where
    undefined) of a point image by the cross product of central differences, oriented towards the camera."""
    n = np.full(points.shape, np.nan, np.float32)
    dx = points[1:-1, 2:] - points[1:-1, :-2]
    dy = points[2:, 1:-1] - points[:-2, 1:-1]
    c = np.cross(dx, dy)
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = c / norm
    flip = np.sum(c * points[1:-1, 1:-1], axis=-1) > 0
    c[flip] *= -1.0
    n[1:-1, 1:-1] = c
    return n


def test_points_and_normals_match_backproject_and_depth_normals() -> None:
    intr = Intrinsics.default(320, 240).scaled(0.5)
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:120, 0:160]
    for k in range(4):
        depth = (0.5 + 0.2 * rng.random((120, 160)) + np.linspace(0, 0.3, 160)[None, :]).astype(np.float32)
        if k == 1:  # a plane with a hole: normals defined and equal along it
            depth[:] = np.float32(0.7) + np.linspace(0, 0.1, 120, dtype=np.float32)[:, None]
        depth[rng.random(depth.shape) < 0.1] = np.nan
        pts = intr.backproject(u, v, depth).astype(np.float32)
        with np.errstate(invalid="ignore", divide="ignore"):
            ref = depth_normals(pts)
        got_pts, got = points_and_normals(depth, float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy))
        assert np.isfinite(ref).any() and np.isnan(ref).any()
        np.testing.assert_array_equal(got_pts, pts)
        np.testing.assert_array_equal(got, ref)


def test_motion_size_matches_the_numpy_form() -> None:
    """``motion_size`` on Python floats gives ``(norm(t), arccos(clip((trace(R) − 1) / 2, −1, 1)))`` of numpy bit for
    bit: random motions, no motion, half turns and a rotation a little off orthonormal (clipped at both ends)."""
    from tracker.filter.motion_model import rotvec_to_matrix
    from tracker.odometry.se3 import motion_size

    rng = np.random.default_rng(12)
    mats = list(rotvec_to_matrix(rng.normal(0.0, 10 ** rng.uniform(-5, 0.4, (400, 1)), (400, 3))))
    mats += [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.eye(3) * (1.0 + 1e-12), -np.eye(3) * (1.0 + 1e-12)]
    for R in mats:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, rng.normal(0.0, 0.01, 3)
        cos = np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        want = (float(np.linalg.norm(T[:3, 3])), float(np.arccos(cos)))
        assert motion_size(T) == want


def test_alignment_median_equals_numpys() -> None:
    """The dense alignment's median (correspondences._median, a branch-free quickselect) gives numpy's median bit for
    bit: odd and even lengths, ties, all values equal, mostly equal (the sorted fallback), sorted and reversed input;
    the robust scale built on it equals the numpy form."""
    from tracker.odometry.correspondences import _median, _robust_scale

    rng = np.random.default_rng(8)
    for n in [*range(1, 40), 600, 601, 1024]:
        for rep in range(12):
            x = rng.normal(size=n) * 10.0 ** rng.integers(-3, 3)
            if rep % 3 == 0:
                x = np.round(x, 1)  # ties
            if rep == 4:
                x[:] = 0.5
            if rep == 5:
                x[rng.random(n) < 0.8] = 0.25
            if rep == 6:
                x = np.sort(x)
            if rep == 7:
                x = np.sort(x)[::-1].copy()
            assert _median(x.copy()) == np.median(x)
    r = rng.standard_t(3, size=1500) * 1e-3
    for n, samples in [(1500, 1024), (900, 1024), (11, 1024)]:
        s = r[0:n:1 if n <= samples else -(-n // samples)]
        want = max(5e-4, 1.4826 * float(np.median(np.abs(s - np.median(s)))))
        assert _robust_scale(r, n, samples, 5e-4) == want
