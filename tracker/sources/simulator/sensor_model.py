"""Depth and colour sensor models of the simulated RGB-D camera.

This is deliberately NOT the tracker's depth likelihood: it imitates a structured-light / stereo depth
camera (Kinect / RealSense class) with

* depth-dependent Gaussian noise ``σ(z) = noise_coeff · z²`` (metres), on depth or on disparity;
* quantisation: 1 mm steps (``quantization="mm"``) or disparity steps of ``disparity_step`` px with
  ``z = focal·baseline / disparity`` (``quantization="disparity"``), or none;
* missing pixels at depth discontinuities (``edge_missing`` of the pixels next to a jump of more than
  ``edge_jump`` · z) and at grazing angles (probability rising from 0 at ``grazing_start_deg`` to 1 at
  ``grazing_end_deg`` between the viewing ray and the surface normal);
* "flying pixels" at edges (``edge_flying`` of the edge pixels take a depth interpolated between the
  fore- and the background);
* random dropouts (``dropout`` of all pixels), and a working range ``[min_range, max_range]``;
* the projector's shadow of a structured-light sensor: background pixels that the pattern projector,
  ``projector_baseline`` metres to the right of the depth camera, cannot see behind a nearer surface get no
  depth (a band to the left of every object, its width the disparity difference ``fx·b·(1/z_fg − 1/z_bg)``);
* a fixed misregistration of the depth image relative to colour: the depth at pixel ``(u, v)`` is the
  scene depth at ``(u + shift_u, v + shift_v)`` (integer pixels, ≤ 1).

Randomness is counter-based (a splitmix64 hash of a per-frame key and the pixel index), so frame ``k``
is bit-identical whenever it is rendered, in any order. Gaussian variates are Irwin–Hall sums of four
12-bit uniforms (unit variance, tails cut at ±3.46 σ).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}
"""Fast-math flags without ``nnan``/``ninf``: the kernels rely on inf/NaN semantics."""

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_MASK16 = np.uint64(0xFFFF)
_MASK8 = np.uint64(0xFF)
_MASK12 = np.uint64(0xFFF)
_S48 = np.uint64(48)


@dataclass(frozen=True)
class DepthSensorModel:
    """Parameters of the simulated depth sensor (defaults imitate a Kinect-class camera at 0.5–1 m).

    * ``noise_coeff``: σ(z) = noise_coeff · z² metres (1.4e-3 → 0.9 mm at 0.8 m).
    * ``noise_on``: ``"depth"`` (Gaussian on z) or ``"disparity"`` (Gaussian on disparity with the same σ(z)).
    * ``quantization``: ``"mm"`` (round to ``quant_step`` metres), ``"disparity"`` (disparity steps) or ``"none"``.
    * ``quant_step``: metres per depth unit for ``"mm"`` (0.001).
    * ``focal_baseline``: f·b in px·m for disparity (525 px · 0.075 m).
    * ``disparity_step``: disparity quantum in px for ``"disparity"`` (1/8 px).
    * ``edge_jump``: relative depth jump (Δz / z) that marks a depth discontinuity (0.02).
    * ``edge_missing``: probability that a pixel at a discontinuity is missing (0.5).
    * ``edge_flying``: probability that it is a flying pixel between fore- and background (0.1).
    * ``grazing_start_deg`` / ``grazing_end_deg``: incidence angles where grazing dropouts begin (75°) /
      become certain (87°).
    * ``dropout``: probability of a random missing pixel anywhere (0.005).
    * ``min_range`` / ``max_range``: working range in metres (0.3 / 4.0); outside it depth is missing.
    * ``shift_u`` / ``shift_v``: depth-to-colour misregistration in whole pixels (1, 0).
    * ``projector_baseline``: metres from the depth camera to the pattern projector, on its right (0.075;
      negative: on its left; 0: no projector shadows).
    """

    noise_coeff: float = 1.4e-3
    noise_on: str = "depth"
    quantization: str = "mm"
    quant_step: float = 0.001
    focal_baseline: float = 525.0 * 0.075
    disparity_step: float = 0.125
    edge_jump: float = 0.02
    edge_missing: float = 0.5
    edge_flying: float = 0.1
    grazing_start_deg: float = 75.0
    grazing_end_deg: float = 87.0
    dropout: float = 0.005
    min_range: float = 0.3
    max_range: float = 4.0
    shift_u: int = 1
    shift_v: int = 0
    projector_baseline: float = 0.075

    def __post_init__(self) -> None:
        if self.noise_on not in ("depth", "disparity"):
            raise ValueError(f"DepthSensorModel.noise_on must be 'depth' or 'disparity', got {self.noise_on!r}")
        if self.quantization not in ("mm", "disparity", "none"):
            raise ValueError(
                f"DepthSensorModel.quantization must be 'mm', 'disparity' or 'none', got {self.quantization!r}"
            )
        if abs(self.shift_u) > 1 or abs(self.shift_v) > 1:
            raise ValueError("DepthSensorModel.shift_u/shift_v must be -1, 0 or 1 pixel")
        for name in ("edge_missing", "edge_flying", "dropout"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"DepthSensorModel.{name} must be a probability in [0, 1]")
        if self.edge_missing + self.edge_flying > 1.0:
            raise ValueError("DepthSensorModel.edge_missing + edge_flying must not exceed 1")

    def sigma(self, z: np.ndarray | float) -> np.ndarray | float:
        """Standard deviation (metres) of the depth noise at depth ``z`` metres (before quantisation)."""
        return self.noise_coeff * np.asarray(z, dtype=float) ** 2

    def projector_shadow(self, clean: np.ndarray, fx: float = 525.0, out: np.ndarray | None = None,
                         rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:  # fmt: skip
        """Bool H×W: the pixels of ``clean`` depth (metres, inf where nothing) the pattern projector cannot reach
        (all False without a projector); ``fx`` the focal length in pixels. ``out``: a bool array to write into
        (returned). ``rows`` = ``(compute, restore, base)``: only the rows ``compute`` marks (bool per row) are
        computed, those ``restore`` marks (and not ``compute``) are copied from ``base`` (bool H×W), the others of
        ``out`` are kept — for a caller that knows which rows of ``clean`` changed since ``out`` was made."""
        if out is None:
            out = np.empty(clean.shape, np.bool_)
        if self.projector_baseline == 0.0:
            out[...] = False
            return out
        fxb, right = float(fx) * abs(self.projector_baseline), self.projector_baseline > 0
        if rows is None:
            _projector_shadow(clean, fxb, right, out)
        else:
            _projector_shadow_rows(clean, fxb, right, out, *rows)
        return out

    def apply(self, clean: np.ndarray, cosang: np.ndarray, key: int, fx: float = 525.0,
              out: np.ndarray | None = None, shadow: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
        """Noisy float32 depth (NaN missing) from noise-free ``clean`` depth (inf where nothing) and
        ``cosang`` = |cos(incidence)|, with the randomness of per-frame ``key`` (uint64); ``fx`` is the focal
        length in pixels (for the projector shadows). ``out``: a float32 array of ``clean``'s shape to write into
        (returned), else a new one. ``shadow``: :meth:`projector_shadow` of ``clean`` when the caller has it (else it
        is computed here)."""
        if out is None:
            out = np.empty(clean.shape, np.float32)
        if shadow is None:
            shadow = self.projector_shadow(clean, fx)
        quant = {"none": 0, "mm": 1, "disparity": 2}[self.quantization]
        _depth_kernel(
            clean,
            cosang,
            out,
            np.uint64(key),
            float(self.noise_coeff),
            self.noise_on == "disparity",
            quant,
            float(self.quant_step),
            float(self.focal_baseline),
            float(self.disparity_step),
            float(self.edge_jump),
            float(self.edge_missing),
            float(self.edge_flying),
            float(np.cos(np.radians(self.grazing_start_deg))),
            float(np.cos(np.radians(self.grazing_end_deg))),
            float(self.dropout),
            float(self.min_range),
            float(self.max_range),
            int(self.shift_u),
            int(self.shift_v),
            shadow,
        )
        return out


@dataclass(frozen=True)
class ColorSensorModel:
    """Parameters of the simulated colour camera.

    * ``noise_sigma``: per-channel pixel noise, 0–255 levels (2.5; triangular-distributed).
    * ``gain_amplitude``: amplitude of the slow global brightness variation (0.06 → ±6 %).
    * ``gain_period``: its period in seconds (7 s), plus a weaker 1.7 s flicker of a quarter of the amplitude.
    * ``ramp_amplitude``: amplitude of a slowly rotating left/right–top/bottom brightness ramp (0.08).
    * ``ramp_period``: seconds per rotation of the ramp direction (23 s).
    * ``vignetting``: relative darkening in the image corners (0.15), growing with the squared distance from
      the image centre.
    * ``blur_sigma``: Gaussian optical blur in pixels (0.6; 3×3 kernel), which also softens the rendered
      edges; 0 disables.
    """

    noise_sigma: float = 2.5
    gain_amplitude: float = 0.06
    gain_period: float = 7.0
    ramp_amplitude: float = 0.08
    ramp_period: float = 23.0
    vignetting: float = 0.15
    blur_sigma: float = 0.6

    def lighting(self, t: float, phase: float) -> tuple[float, float, float]:
        """Global gain and the (u, v) ramp coefficients at time ``t`` seconds (``phase`` in radians, seeded)."""
        g = 1.0 + self.gain_amplitude * (
            np.sin(2 * np.pi * t / self.gain_period + phase) + 0.25 * np.sin(2 * np.pi * t / 1.7 + 2 * phase)
        )
        ang = 2 * np.pi * t / self.ramp_period + phase
        return float(g), float(self.ramp_amplitude * np.cos(ang)), float(self.ramp_amplitude * np.sin(ang))

    def apply(self, color: np.ndarray, key: int, t: float, phase: float, out: np.ndarray | None = None,
              scratch: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
        """uint8 RGB from the float (0..255) rendered colour, with lighting variation and noise; ``out``: a uint8
        array of ``color``'s shape to write into (returned; any strides), else a new one; ``scratch``: a float32
        array of ``color``'s shape (not ``color`` itself) the blurred colour is written into, else a new one (a
        frame's fresh 3.7 MB costs ~0.4 ms of page faults)."""
        g, ru, rv = self.lighting(t, phase)
        if self.blur_sigma > 0:
            # OpenCV writes into ``scratch`` when it fits and returns a new array otherwise (or without one)
            color = cv2.GaussianBlur(color, (3, 3), float(self.blur_sigma), dst=scratch)
        if out is None:
            out = np.empty(color.shape, np.uint8)
        # the kernel reads and writes C-contiguous buffers (the renderer's and the frame slots are)
        target = out if out.flags.c_contiguous else np.empty(color.shape, np.uint8)
        _color_kernel(np.ascontiguousarray(color), target, np.uint64(key), g, ru, rv, float(self.vignetting),
                      float(self.noise_sigma))  # fmt: skip
        if target is not out:
            out[...] = target
        return out


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _mix(x):
    x = (x ^ (x >> _S30)) * _M1
    x = (x ^ (x >> _S27)) * _M2
    return x ^ (x >> _S31)


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _hash(key, i, stream):
    return _mix(key + (np.uint64(i) * np.uint64(4) + np.uint64(stream) + np.uint64(1)) * _GOLDEN)


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _u16(h, k):
    return np.float64((h >> np.uint64(16 * k)) & _MASK16) * (1.0 / 65536.0) + (0.5 / 65536.0)


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _gauss12(h):
    s = 0.0
    for k in range(4):
        s += np.float64((h >> np.uint64(12 * k)) & _MASK12) * (1.0 / 4096.0)
    return (s - 2.0 + 2.0 / 4096.0) * 1.7320508075688772


@nb.njit(cache=True, fastmath=_FM)
def _depth_pixel(clean, cosang, key, coeff, on_disp, quant, qstep, fb, dstep, jump, p_miss, p_fly, cos_start, cos_end,
                 p_drop, zmin, zmax, su, sv, shadow, v, u, h1):  # fmt: skip
    """The noisy depth of output pixel ``(v, u)`` (NaN missing), every case; ``h1`` its first hash (stream 0)."""
    h, w = clean.shape
    nan = np.float32(np.nan)
    vs = v + sv
    us = u + su
    if vs < 0 or vs >= h or us < 0 or us >= w:
        return nan
    z = clean[vs, us]
    if not (z >= zmin and z <= zmax) or shadow[vs, us]:
        return nan
    i = v * w + u
    # bits 0..47: four 12-bit uniforms for the Gaussian; bits 48..63: the dropout draw
    r_drop = np.float64(h1 >> _S48) * (1.0 / 65536.0)
    if r_drop < p_drop:
        return nan
    # grazing incidence
    c = cosang[vs, us]
    if c < cos_start:
        p = (cos_start - c) / (cos_start - cos_end)
        if _u16(_hash(key, i, 2), 0) < p:
            return nan
    # depth discontinuity: farthest / nearest 4-neighbour
    znear = z
    zfar = z
    if vs > 0:
        zn = clean[vs - 1, us]
        znear = min(znear, zn)
        zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
    if vs < h - 1:
        zn = clean[vs + 1, us]
        znear = min(znear, zn)
        zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
    if us > 0:
        zn = clean[vs, us - 1]
        znear = min(znear, zn)
        zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
    if us < w - 1:
        zn = clean[vs, us + 1]
        znear = min(znear, zn)
        zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
    thr = jump * z
    edge_fg = zfar - z > thr  # z is the foreground next to a jump
    edge_bg = z - znear > thr  # z is the background next to a jump
    if edge_fg or edge_bg:
        h3 = _hash(key, i, 3)
        r_edge = _u16(h3, 0)
        if r_edge < p_miss:
            return nan
        if r_edge < p_miss + p_fly:
            other = zfar if edge_fg else znear
            if other > zmax:
                return nan
            z = z + (other - z) * _u16(h3, 1)
    n = _gauss12(h1)
    sigma = coeff * z * z
    if on_disp:
        d = fb / z
        d = d + n * sigma * fb / (z * z)
        if quant == 2:
            d = np.floor(d / dstep + 0.5) * dstep
        if d <= 0.0:
            return nan
        z = fb / d
    else:
        z = z + n * sigma
        if quant == 2:
            d = np.floor(fb / z / dstep + 0.5) * dstep
            z = fb / d
    if quant == 1:
        z = np.floor(z / qstep + 0.5) * qstep
    if z < zmin or z > zmax:
        return nan
    return np.float32(z)


@nb.njit(cache=True, fastmath=_FM)
def _depth_kernel(clean, cosang, out, key, coeff, on_disp, quant, qstep, fb, dstep, jump, p_miss, p_fly, cos_start,
                  cos_end, p_drop, zmin, zmax, su, sv, shadow):  # fmt: skip
    """Every output pixel's :func:`_depth_pixel`. With noise on depth and millimetre quantisation (the default model)
    the pixels whose source pixel and its four neighbours lie inside the image take a branch-free loop (it vectorises,
    about a quarter faster) for the common case (in range, lit by the projector, not dropped, not grazing, no
    discontinuity); the few others (a flag per pixel) and the border rows and columns take :func:`_depth_pixel`. The
    same values either way (the same operations on the same inputs; tests/test_simulator_kernels.py)."""
    h, w = clean.shape
    nan = np.float32(np.nan)
    hashes = np.empty(w, np.uint64)  # a row's first hashes, in a loop of their own (it vectorises)
    rare = np.ones(w, np.bool_)  # pixels that need the per-pixel path (the border columns always do)
    ulo, uhi = max(0, 1 - su), min(w, w - 1 - su)  # output columns whose source column has both neighbours
    n = max(uhi - ulo, 0)
    fast = not on_disp and quant == 1
    far = zmax * 2.0
    for v in range(h):
        vs = v + sv
        row = v * w
        for u in range(w):
            hashes[u] = _hash(key, row + u, 0)
        if not fast or vs < 1 or vs >= h - 1:
            for u in range(w):
                out[v, u] = _depth_pixel(clean, cosang, key, coeff, on_disp, quant, qstep, fb, dstep, jump, p_miss,
                                         p_fly, cos_start, cos_end, p_drop, zmin, zmax, su, sv, shadow, v, u,
                                         hashes[u])  # fmt: skip
            continue
        # the row's arrays as slices indexed from 0 (the source column of output column ulo + k is s0 + k): LLVM then
        # knows the indices are not negative and loads the neighbours as vectors, not gathers (1.8x faster, the same
        # values)
        s0 = ulo + su
        zc = clean[vs, s0 : s0 + n]
        zu = clean[vs - 1, s0 : s0 + n]
        zd = clean[vs + 1, s0 : s0 + n]
        zl = clean[vs, s0 - 1 : s0 - 1 + n]
        zr = clean[vs, s0 + 1 : s0 + 1 + n]
        cs = cosang[vs, s0 : s0 + n]
        sh = shadow[vs, s0 : s0 + n]
        hs = hashes[ulo : ulo + n]
        o = out[v, ulo : ulo + n]
        flag = rare[ulo : ulo + n]
        for k in range(n):
            z = zc[k]
            h1 = hs[k]
            z0 = zu[k]
            z1 = zd[k]
            z2 = zl[k]
            z3 = zr[k]
            znear = min(min(min(min(z, z0), z1), z2), z3)
            zfar = max(max(max(max(z, z0 if z0 < zmax else far), z1 if z1 < zmax else far), z2 if z2 < zmax else far),
                       z3 if z3 < zmax else far)  # fmt: skip
            thr = jump * z
            r_drop = np.float64(h1 >> _S48) * (1.0 / 65536.0)
            kept = (z >= zmin) & (z <= zmax) & (not sh[k]) & (r_drop >= p_drop)
            plain = kept & (cs[k] >= cos_start) & (not (zfar - z > thr)) & (not (z - znear > thr))
            zq = z + _gauss12(h1) * (coeff * z * z)
            zq = np.floor(zq / qstep + 0.5) * qstep
            val = np.float32(zq) if (zq >= zmin) & (zq <= zmax) else nan
            o[k] = val if plain else nan
            flag[k] = kept & (not plain)
        for u in range(w):
            if rare[u]:
                out[v, u] = _depth_pixel(clean, cosang, key, coeff, on_disp, quant, qstep, fb, dstep, jump, p_miss,
                                         p_fly, cos_start, cos_end, p_drop, zmin, zmax, su, sv, shadow, v, u,
                                         hashes[u])  # fmt: skip


@nb.njit(cache=True, inline="always", fastmath=_FM, error_model="numpy")
def _columns(clean, v, fxb, right, c):
    """The projector column of every pixel of row ``v`` into ``c`` (inf depth → disparity 0). Branch-free so that
    it vectorises: the kernels that inline it take numpy's error model (with Python's every division checked its
    divisor for zero, a branch per pixel, and the loop stayed scalar; the same values; a zero depth would now give an
    infinite column instead of raising)."""
    w = clean.shape[1]
    if right:
        for u in range(w):
            c[u] = u - fxb / clean[v, u]
    else:
        for u in range(w):
            c[u] = u + fxb / clean[v, u]


@nb.njit(cache=True, inline="always", fastmath=_FM)
def _scan(c, s, right):
    """One row's shadow ``s`` from its projector columns ``c``: a running minimum from the right (``right``) or
    maximum from the left (a serial chain: :func:`_shadow_rows` runs four rows' chains side by side)."""
    w = c.shape[0]
    if right:
        m = 1e30
        for i in range(w):
            u = w - 1 - i
            s[u] = m < c[u] - 0.5
            m = min(m, c[u])
    else:
        m = -1e30
        for u in range(w):
            s[u] = m > c[u] + 0.5
            m = max(m, c[u])


@nb.njit(cache=True, fastmath=_FM, error_model="numpy")
def _shadow_rows(clean, fxb, right, shadow, rows):
    """:func:`_projector_shadow` of the rows listed in ``rows`` (int64), four at a time: the running minimum (or
    maximum) of a row is a chain of dependent steps, so four rows' chains in one loop take about the time of one
    (the same comparisons on the same values: the same masks)."""
    w = clean.shape[1]
    n = rows.shape[0]
    c = np.empty((4, w))
    for g in range(0, n, 4):
        k = min(4, n - g)
        for j in range(k):
            _columns(clean, rows[g + j], fxb, right, c[j])
        if k < 4:
            for j in range(k):
                _scan(c[j], shadow[rows[g + j]], right)
            continue
        c0, c1, c2, c3 = c[0], c[1], c[2], c[3]
        s0, s1, s2, s3 = shadow[rows[g]], shadow[rows[g + 1]], shadow[rows[g + 2]], shadow[rows[g + 3]]
        if right:
            m0 = m1 = m2 = m3 = 1e30
            for i in range(w):
                u = w - 1 - i
                x0, x1, x2, x3 = c0[u], c1[u], c2[u], c3[u]
                s0[u] = m0 < x0 - 0.5
                s1[u] = m1 < x1 - 0.5
                s2[u] = m2 < x2 - 0.5
                s3[u] = m3 < x3 - 0.5
                m0 = min(m0, x0)
                m1 = min(m1, x1)
                m2 = min(m2, x2)
                m3 = min(m3, x3)
        else:
            m0 = m1 = m2 = m3 = -1e30
            for u in range(w):
                x0, x1, x2, x3 = c0[u], c1[u], c2[u], c3[u]
                s0[u] = m0 > x0 + 0.5
                s1[u] = m1 > x1 + 0.5
                s2[u] = m2 > x2 + 0.5
                s3[u] = m3 > x3 + 0.5
                m0 = max(m0, x0)
                m1 = max(m1, x1)
                m2 = max(m2, x2)
                m3 = max(m3, x3)


@nb.njit(cache=True, fastmath=_FM, error_model="numpy")
def _projector_shadow(clean, fxb, right, shadow):
    """Mark pixels hidden from a projector ``fxb / fx`` metres to the right (``right``) or left of the camera.

    Along a row the projector column of pixel u is ``c(u) = u ∓ fxb / z(u)``; a pixel is in shadow when a pixel
    on the projector's side has a smaller (right) / larger (left) projector column, i.e. a nearer surface
    blocks the projector's ray.
    """
    _shadow_rows(clean, fxb, right, shadow, np.arange(clean.shape[0]))


@nb.njit(cache=True, fastmath=_FM, error_model="numpy")
def _projector_shadow_rows(clean, fxb, right, shadow, compute, restore, base):
    """:func:`_projector_shadow` of the rows ``compute`` marks (bool per row); the rows ``restore`` marks (and not
    ``compute``) are copied from ``base``; the others are left as they are."""
    h, w = clean.shape
    rows = np.flatnonzero(compute[:h])
    for v in range(h):
        if restore[v] and not compute[v]:
            for u in range(w):
                shadow[v, u] = base[v, u]
    _shadow_rows(clean, fxb, right, shadow, rows)


@nb.njit(cache=True, fastmath=_FM)
def _color_kernel(color, out, key, gain, ramp_u, ramp_v, vignetting, sigma):
    # A row's hashes first, then its pixels, clipped without branches: both loops vectorise (the same values as one
    # loop with if/elif clipping, about 2.5× faster). The pixel loop reads and writes the row as flat slices indexed
    # from 0 (``3·u + c``): the channel stride is then a constant 3 and LLVM vectorises the interleaved channels
    # (with the 3-D arrays' run-time shape it stayed scalar: 1.9 → 0.9 ms a 640×480 frame, the same values)
    h, w, _ = color.shape
    flat_in = color.reshape(-1)
    flat_out = out.reshape(-1)
    scale = sigma / 104.51314746403095  # std of (b1 + b2 - 255) for two uniform bytes
    hashes = np.empty(w, np.uint64)
    dus = np.empty(w)
    for u in range(w):
        dus[u] = u / w - 0.5
    for v in range(h):
        dv = v / h - 0.5
        gv = gain + ramp_v * dv
        row = v * w
        for u in range(w):
            hashes[u] = _hash(key, row + u, 2)
        row_in = flat_in[3 * row : 3 * (row + w)]
        row_out = flat_out[3 * row : 3 * (row + w)]
        for u in range(w):
            du = dus[u]
            g = (gv + ramp_u * du) * (1.0 - vignetting * 2.0 * (du * du + dv * dv))
            hh = hashes[u]
            for c in range(3):
                b1 = np.float64((hh >> np.uint64(16 * c)) & _MASK8)
                b2 = np.float64((hh >> np.uint64(16 * c + 8)) & _MASK8)
                val = row_in[3 * u + c] * g + (b1 + b2 - 255.0) * scale + 0.5
                row_out[3 * u + c] = np.uint8(min(max(val, 0.0), 255.0))
