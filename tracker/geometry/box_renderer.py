"""Exact depth rendering of boxes by ray–box (slab) intersection, compiled with numba.

Depth here is the camera-frame z of the first surface hit along a pixel's ray (metres, ``inf`` = no hit).
A pixel's ray is ``r = ((u − cx)/fx, (v − cy)/fy, 1)``, so the ray parameter of a hit equals its depth.
Boxes are given as a pose (rotation ``R`` body→camera, translation ``t`` = box centre in the camera frame,
optionally an offset ``c`` of the box centre in the body frame) and half extents ``h`` (metres).

The particle filter renders one object for many particles at a list of evaluated pixels
(:func:`render_boxes_at_pixels`); :func:`render_box_depth` renders whole images (tests, baselines).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics

_EPS = 1e-12


@nb.njit(cache=True, inline="always")
def _slab(d, o, h, tnear, tfar):
    """Clip the ray interval ``[tnear, tfar]`` by one slab ``|o + t d| <= h`` of a box (one body axis).

    A ray parallel to the slab (``|d| < eps``) either stays inside it or misses (returns an empty interval).
    """
    if abs(d) < _EPS:
        if abs(o) > h:
            return np.inf, -np.inf
        return tnear, tfar
    inv = 1.0 / d
    t1 = (-h - o) * inv
    t2 = (h - o) * inv
    if t1 > t2:
        t1, t2 = t2, t1
    return max(tnear, t1), min(tfar, t2)


@nb.njit(cache=True, inline="always")
def _slab_depth(r00, r01, r02, r10, r11, r12, r20, r21, r22, ox, oy, oz, hx, hy, hz, rx, ry, rz):
    """Depth of the first hit of ray ``(rx, ry, rz)`` from the origin with a box.

    ``r..`` is Rᵀ (camera→body rotation), ``(ox, oy, oz)`` the camera origin in the box frame (relative to the
    box centre), ``h`` the half extents. Returns ``inf`` when the ray misses.
    """
    dx = r00 * rx + r01 * ry + r02 * rz
    dy = r10 * rx + r11 * ry + r12 * rz
    dz = r20 * rx + r21 * ry + r22 * rz
    tnear = -np.inf
    tfar = np.inf
    tnear, tfar = _slab(dx, ox, hx, tnear, tfar)
    tnear, tfar = _slab(dy, oy, hy, tnear, tfar)
    tnear, tfar = _slab(dz, oz, hz, tnear, tfar)
    if tnear > tfar or tfar <= 0.0:
        return np.inf
    return tnear if tnear > 0.0 else 1e-6


@nb.njit(cache=True)
def render_boxes_at_pixels(R, t, center, half, obj, particles, rays, pu, pv, subset, fx, fy, cx, cy, out, loc, dirty):
    """Render box ``obj`` for the listed particles at the listed pixels into ``out[j, loc[obj, i]]``.

    * ``R`` (N, K, 3, 3) body→camera rotations, ``t`` (N, K, 3) body origins in the camera frame.
    * ``center`` (K, 3) box centre in the body frame, ``half`` (K, 3) half extents (metres).
    * ``particles`` (M,) particle indices; ``subset`` (S,) indices into the pixel list.
    * ``rays`` (P, 3) ray per evaluated pixel, ``pu``/``pv`` (P,) its full-resolution pixel coordinates.
    * ``out`` (N, M) float32 depth buffers, one column per (part, pixel) pair of the part's region of interest;
      ``loc`` (K, P) int64 gives the column of part k at pixel i, or −1 (pixel outside the part's region: skipped).
      Pixels outside the box's projected bounding rectangle get ``inf``.
    * ``dirty`` (N, P) uint8: set to 1 where a written depth differs from the previous one.

    A particle whose pose of ``obj`` equals the previous listed particle's (copies left by a resampling) takes that
    particle's depths instead of casting its rays again (the same values).
    """
    hx, hy, hz = half[obj, 0], half[obj, 1], half[obj, 2]
    for jj in range(particles.shape[0]):
        j = particles[jj]
        if jj > 0 and same_pose(R, t, obj, particles[jj - 1], j):
            copy_depth_row(particles[jj - 1], j, obj, subset, out, loc, dirty)
            continue
        Rm = R[j, obj]
        # box centre in the camera frame
        bx = Rm[0, 0] * center[obj, 0] + Rm[0, 1] * center[obj, 1] + Rm[0, 2] * center[obj, 2] + t[j, obj, 0]
        by = Rm[1, 0] * center[obj, 0] + Rm[1, 1] * center[obj, 1] + Rm[1, 2] * center[obj, 2] + t[j, obj, 1]
        bz = Rm[2, 0] * center[obj, 0] + Rm[2, 1] * center[obj, 1] + Rm[2, 2] * center[obj, 2] + t[j, obj, 2]
        # camera origin in the box frame: o = Rᵀ (0 − b)
        ox = -(Rm[0, 0] * bx + Rm[1, 0] * by + Rm[2, 0] * bz)
        oy = -(Rm[0, 1] * bx + Rm[1, 1] * by + Rm[2, 1] * bz)
        oz = -(Rm[0, 2] * bx + Rm[1, 2] * by + Rm[2, 2] * bz)
        # projected bounding rectangle from the 8 corners
        umin = np.inf
        umax = -np.inf
        vmin = np.inf
        vmax = -np.inf
        behind = False
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                for sz in (-1.0, 1.0):
                    px = bx + Rm[0, 0] * sx * hx + Rm[0, 1] * sy * hy + Rm[0, 2] * sz * hz
                    py = by + Rm[1, 0] * sx * hx + Rm[1, 1] * sy * hy + Rm[1, 2] * sz * hz
                    pz = bz + Rm[2, 0] * sx * hx + Rm[2, 1] * sy * hy + Rm[2, 2] * sz * hz
                    if pz < 1e-3:
                        behind = True
                    else:
                        u = fx * px / pz + cx
                        v = fy * py / pz + cy
                        umin = min(umin, u)
                        umax = max(umax, u)
                        vmin = min(vmin, v)
                        vmax = max(vmax, v)
        if behind:
            umin = -np.inf
            umax = np.inf
            vmin = -np.inf
            vmax = np.inf
        umin -= 1.0
        umax += 1.0
        vmin -= 1.0
        vmax += 1.0
        for ii in range(subset.shape[0]):
            i = subset[ii]
            col = loc[obj, i]
            if col < 0:
                continue
            if pu[i] < umin or pu[i] > umax or pv[i] < vmin or pv[i] > vmax:
                d = np.inf
            else:
                d = _slab_depth(
                    Rm[0, 0], Rm[1, 0], Rm[2, 0], Rm[0, 1], Rm[1, 1], Rm[2, 1], Rm[0, 2], Rm[1, 2], Rm[2, 2],
                    ox, oy, oz, hx, hy, hz, rays[i, 0], rays[i, 1], rays[i, 2],
                )
            if out[j, col] != d:
                out[j, col] = d
                dirty[j, i] = 1


@nb.njit(cache=True, inline="always")
def same_pose(R, t, obj, a, b):
    """Do particles ``a`` and ``b`` have exactly the same pose of part ``obj`` (``R`` (N, K, 3, 3), ``t`` (N, K, 3))?"""
    for r in range(3):
        if t[a, obj, r] != t[b, obj, r]:
            return False
        for c in range(3):
            if R[a, obj, r, c] != R[b, obj, r, c]:
                return False
    return True


@nb.njit(cache=True)
def copy_depth_row(src, j, obj, subset, out, loc, dirty):
    """Particle ``j`` takes particle ``src``'s depths of part ``obj`` at the ``subset`` pixels (rendered just
    before in the same call), flagging in ``dirty`` the pixels whose depth changes (as a render would)."""
    for ii in range(subset.shape[0]):
        i = subset[ii]
        col = loc[obj, i]
        if col < 0:
            continue
        d = out[src, col]
        if out[j, col] != d:
            out[j, col] = d
            dirty[j, i] = 1


def pixel_rays(intrinsics: Intrinsics, pu: np.ndarray, pv: np.ndarray) -> np.ndarray:
    """Rays ``(P, 3)`` with unit z through full-resolution pixel coordinates ``pu, pv``."""
    pu = np.asarray(pu, np.float64)
    pv = np.asarray(pv, np.float64)
    return np.stack([(pu - intrinsics.cx) / intrinsics.fx, (pv - intrinsics.cy) / intrinsics.fy, np.ones_like(pu)], 1)


def render_box_depth(
    intrinsics: Intrinsics,
    poses: list,
    sizes: list[tuple[float, float, float]],
    downsample: int = 1,
) -> np.ndarray:
    """Depth image (float32 metres, ``inf`` = background) of boxes with mutual occlusion (z-buffer).

    ``poses``: :class:`~tracker.geometry.pose.Pose` of each box centre (camera frame); ``sizes``: full edge lengths.
    ``downsample`` renders every ``downsample``-th pixel (at the block centres used by the tracker).
    """
    f = int(downsample)
    off = (f - 1) // 2
    us = np.arange(off, intrinsics.width, f)
    vs = np.arange(off, intrinsics.height, f)
    uu, vv = np.meshgrid(us, vs)
    pu = uu.ravel().astype(np.float64)
    pv = vv.ravel().astype(np.float64)
    rays = pixel_rays(intrinsics, pu, pv)
    k = len(poses)
    if k == 0:
        return np.full(uu.shape, np.inf, np.float32)
    R = np.stack([p.R for p in poses])[None].astype(np.float64)
    t = np.stack([p.t for p in poses])[None].astype(np.float64)
    half = np.asarray(sizes, np.float64).reshape(k, 3) / 2.0
    center = np.zeros((k, 3))
    out = np.full((1, k * pu.size), np.inf, np.float32)
    loc = np.arange(k * pu.size, dtype=np.int64).reshape(k, pu.size)
    subset = np.arange(pu.size, dtype=np.int64)
    parts = np.zeros(1, np.int64)
    dirty = np.zeros((1, pu.size), np.uint8)
    for obj in range(k):
        render_boxes_at_pixels(
            R, t, center, half, obj, parts, rays, pu, pv, subset,
            intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, out, loc, dirty,
        )
    return out[0].reshape(k, pu.size).min(axis=0).reshape(uu.shape)


@nb.njit(cache=True)
def box_depths(R, t, center, half, pu, pv, fx, fy, cx, cy):
    """Depth (m, float64 (P,); inf off the silhouette) of the box ``(center, half)`` at pose ``(R, t)`` at the pixels
    ``(pu, pv)`` (float64 (P,)), as :func:`tracker.filter.colour_input.box_surface_depth` gives it: the same renderer
    (:func:`render_boxes_at_pixels`), rays and float32 depths."""
    p = pu.shape[0]
    rays = np.empty((p, 3))
    for i in range(p):
        rays[i, 0] = (pu[i] - cx) / fx
        rays[i, 1] = (pv[i] - cy) / fy
        rays[i, 2] = 1.0
    Rs = np.empty((1, 1, 3, 3))
    ts = np.empty((1, 1, 3))
    for a in range(3):
        ts[0, 0, a] = t[a]
        for b in range(3):
            Rs[0, 0, a, b] = R[a, b]
    out = np.full((1, p), np.inf, np.float32)
    idx = np.arange(p)
    render_boxes_at_pixels(Rs, ts, center.reshape(1, 3), half.reshape(1, 3), 0, np.zeros(1, np.int64), rays, pu, pv,
                           idx, fx, fy, cx, cy, out, idx.reshape(1, p), np.zeros((1, p), np.uint8))
    res = np.empty(p)
    for i in range(p):
        res[i] = np.float64(out[0, i])
    return res
