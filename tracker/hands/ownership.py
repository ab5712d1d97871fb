"""Which hand each skin pixel belongs to while two hands touch or overlap (product addition to hand-tracking spec §6;
``HandTrackerConfig.ownership``).

Two hands of one person have one skin colour, so where they touch their skin forms one 4-connected colour
component. The section-6 mode (eqs. 6.54–6.58) then boxes both hands at once, or neither: on the tuning seeds of
``hands-s2`` most of the lost box F-score was in frames where the two hands' boxes overlap. This module keeps a
per-pixel owner map of the working frame (0 = nobody, else a track key) that carries each hand's identity through the
overlap with the thesis's own motion feature, the optical flow:

* Propagation (:func:`propagate`): every skin pixel of B^c_k inside the ROI takes, through the backward flow
  f^{b,1}_k (frame k → k−1), the owner at k−1 of the pixel it came from. A skin pixel that came from nobody's pixel
  (a part of a hand coming into view) takes the owner of the nearest owned pixel of its own colour component. An
  owner is kept only within its track's box, moved by its velocity and grown by :data:`NEAR_GROW` of its size.
* Per-track components (:func:`track_features`): only when some colour component of B^c_k holds pixels of two owners
  (the hands touch), each track's section-6 test and re-seeding see the components of B^c_k without the pixels the
  other tracks own; the colour mask, motion segmentations and likelihood stay the shared ones (excluding the other
  hand's pixels from the likelihood as well did worse on the tuning seeds). One hand alone, or two hands apart, are
  tracked exactly as without this module.
* After the step (:func:`settle`): the owner map of frame k is the propagated one, kept within each owner's grown
  box (after the step); skin pixels nobody owns inside one track's box go to that track, inside several to the track
  with the nearest box centre; only tracks that are certain of their box claim pixels (a share of their particles in
  the section-6 mode, so the box is a colour component's own box, :data:`tracker.hands.tracker.CLAIM_CERTAIN`), or a
  track just started on a given box (``HandTracker.start_track``). An uncertain box (e.g. a thin palm cut of a hand
  still entering) would otherwise claim part of the other hand and keep it.

Coordinates: the owner map is in working pixels of the whole frame; ROI arrays have origin ``feats.roi[:2]``; boxes
are (u0, v0, u1, v1) in image coordinates (working px). Track keys are positive integers that stay with a track
object (ids may be swapped between tracks).
"""

from __future__ import annotations

import dataclasses

import cv2
import numba as nb
import numpy as np

from tracker.hands.features import HandFeatures, components

NEAR_GROW = 0.5
"""A track may own pixels within its box grown by this fraction of its size on every side."""


@nb.njit(cache=True, nogil=True)
def _pull(mcur, fb, owner_prev, ox, oy):
    """Owner (int32 [h, w], ROI grid) of every set pixel of ``mcur`` from the owner map of frame k−1 (whole frame) at
    the pixel its backward flow ``fb`` [h, w, 2] (px, frame k → k−1) points to (rounded, inside the frame); 0 where
    none."""
    h, w = mcur.shape
    H, W = owner_prev.shape
    out = np.zeros((h, w), np.int32)
    for v in range(h):
        for u in range(w):
            if not mcur[v, u]:
                continue
            x = int(np.floor(u + ox + fb[v, u, 0] + 0.5))
            y = int(np.floor(v + oy + fb[v, u, 1] + 0.5))
            if 0 <= x < W and 0 <= y < H:
                out[v, u] = owner_prev[y, x]
    return out


def _fill_nearest(own: np.ndarray, mask: np.ndarray, cc: np.ndarray) -> np.ndarray:
    """Unowned set pixels of ``mask`` take the owner of the nearest owned pixel (Euclidean) if it lies in the same
    colour component (labels ``cc``)."""
    free = (mask > 0) & (own == 0)
    if not free.any() or not (own > 0).any():
        return own
    src = (own == 0).astype(np.uint8)  # distance to the nearest owned pixel (the zero pixels of src)
    _, lab = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(own > 0)  # DIST_LABEL_PIXEL numbers the zero pixels of src in raster order, as nonzero does
    order = np.zeros(int(lab.max()) + 1, np.int64)
    order[lab[ys, xs]] = np.arange(len(ys))
    fy, fx = np.nonzero(free)
    k = order[lab[fy, fx]]
    ny, nx = ys[k], xs[k]
    same = cc[fy, fx] == cc[ny, nx]
    out = own.copy()
    out[fy[same], fx[same]] = own[ny[same], nx[same]]
    return out


def grown_box(state: np.ndarray, grow: float = NEAR_GROW) -> tuple[float, float, float, float]:
    """(u0, v0, u1, v1) of a state's box (x, y, w, h, x', y') moved by its velocity and grown by ``grow`` × its size
    on every side."""
    x, y, w, h, vx, vy = (float(v) for v in state[:6])
    return (x + vx - (0.5 + grow) * w, y + vy - (0.5 + grow) * h, x + vx + (0.5 + grow) * w,
            y + vy + (0.5 + grow) * h)  # fmt: skip


def _within(own: np.ndarray, keys: list[int], boxes: list[tuple[float, float, float, float]], ox: int,
            oy: int) -> np.ndarray:  # fmt: skip
    """``own`` (ROI grid, origin (ox, oy)) with the owner dropped where a pixel lies outside its owner's box."""
    out = own.copy()
    h, w = own.shape
    vv, uu = np.mgrid[0:h, 0:w]
    uu = uu + ox
    vv = vv + oy
    for key, b in zip(keys, boxes, strict=True):
        sel = own == key
        if sel.any():
            out[sel & ((uu < b[0]) | (uu > b[2]) | (vv < b[1]) | (vv > b[3]))] = 0
    return out


def propagate(feats: HandFeatures, owner_prev: np.ndarray | None, keys: list[int],
              states: list[np.ndarray]) -> np.ndarray | None:  # fmt: skip
    """Owner of every skin pixel of B^c_k in the ROI (int32, ROI grid; 0 = nobody) from the owner map of frame k−1
    (module docstring) for the live tracks ``keys`` with their states at k−1; None without a map."""
    if owner_prev is None:
        return None
    ox, oy = feats.roi[0], feats.roi[1]
    own = _pull(feats.mcur, np.ascontiguousarray(feats.fb[0], np.float32), owner_prev, ox, oy)
    alive = np.zeros(max(int(own.max()), max(keys, default=0)) + 1, bool)
    alive[keys] = True
    own[~alive[own]] = 0
    boxes = [grown_box(s) for s in states]
    own = _within(own, keys, boxes, ox, oy)
    own = _fill_nearest(own, feats.mcur, feats.cc)
    return _within(own, keys, boxes, ox, oy)


def shared(own: np.ndarray, cc: np.ndarray) -> bool:
    """Whether some colour component (labels ``cc``) holds pixels of two owners."""
    sel = own > 0
    if not sel.any():
        return False
    pairs = np.unique(np.stack([cc[sel], own[sel]], axis=1), axis=0)
    return len(np.unique(pairs[:, 0])) < len(pairs)


def track_features(feats: HandFeatures, own: np.ndarray, key: int, image_size: tuple[int, int]) -> HandFeatures:
    """``feats`` for the track ``key``: the connected components (4-connectivity) of B^c_k without the pixels other
    tracks own (``own``), cut flags as in :func:`tracker.hands.features.compute_features`; everything else shared."""
    mcur = feats.mcur.copy()
    mcur[(own > 0) & (own != key)] = 0
    cc, n_comp, area, boxes, cut = components(mcur, feats.roi, image_size)
    return dataclasses.replace(feats, cc=cc, n_comp=n_comp, cc_area=area, cc_box=boxes, cc_cut=cut)


def settle(shape: tuple[int, int], roi: tuple[int, int, int, int], mcur: np.ndarray, own: np.ndarray | None,
           keys: list[int], states: list[np.ndarray], claim: list[bool] | None = None) -> np.ndarray:  # fmt: skip
    """The owner map of frame k (int32 of the working frame's ``shape`` (h, w); 0 = nobody) after the step: the
    propagated owners ``own`` (ROI grid, or None) on the skin pixels ``mcur`` of the ROI, each kept within its track's
    box (``states`` after the step, velocity not applied) grown by NEAR_GROW; a skin pixel inside one or more tracks'
    boxes that none of them owns goes to the one whose box centre is nearest, among the tracks that may ``claim``
    (default all)."""
    out = np.zeros(shape, np.int32)
    x0, y0, _, _ = roi
    o = np.zeros(mcur.shape, np.int32) if own is None else own.copy()
    o[mcur == 0] = 0
    still = [np.concatenate([np.asarray(st[:4], float), [0.0, 0.0]]) for st in states]
    o = _within(o, keys, [grown_box(st) for st in still], x0, y0)
    skin = mcur > 0
    if skin.any() and keys:
        h, w = mcur.shape
        vv, uu = np.mgrid[0:h, 0:w]
        uu = uu + x0
        vv = vv + y0
        inside = []
        for st in still:
            b = grown_box(st, 0.0)
            inside.append(skin & (uu >= b[0]) & (uu <= b[2]) & (vv >= b[1]) & (vv <= b[3]))
        count = np.sum(inside, axis=0)
        best = np.full(mcur.shape, np.inf)
        near = np.zeros(mcur.shape, np.int32)
        keep = np.zeros(mcur.shape, bool)
        for key, st, ins, c in zip(keys, still, inside, claim or [True] * len(keys), strict=True):
            if not c:
                continue
            keep |= ins & (o == key)
            d = (uu - st[0]) ** 2 + (vv - st[1]) ** 2
            take = ins & (d < best)
            near[take] = key
            best[take] = d[take]
        # in one box and nobody's: that box's track; in several boxes and not owned by a claiming one of them: the
        # nearest claiming centre (nobody if none of them may claim)
        fill = (count >= 1) & ~keep & ((count > 1) | (o == 0))
        o[fill] = near[fill]
    out[y0 : y0 + mcur.shape[0], x0 : x0 + mcur.shape[1]] = o
    return out
