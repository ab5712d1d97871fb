"""HSV colour ranges with the hue in degrees and wrap-around at 0°/360° (spec section 2.1–2.2).

Conventions of this module:

* Hue ``h`` in degrees, [0°, 360°) (eq. 3.1); saturation ``s`` and value ``v`` as **fractions in [0, 1]**
  (eqs 3.2–3.3 with RGB scaled to [0, 1]).
* A range whose ``h_lo_deg > h_hi_deg`` crosses 0°: it contains hues in [h_lo, 360°) ∪ [0°, h_hi].
  ``h_lo_deg = 0, h_hi_deg = 360`` is the full hue circle.
* OpenCV 8-bit HSV images (``cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)``) store H/2 in [0, 180) and S, V
  scaled to [0, 255]; :meth:`HSVRange.opencv_bounds` converts a range to that form (two intervals when the
  hue range wraps) and :meth:`HSVRange.mask` applies it with ``cv2.inRange``.

Hue statistics (calibration, :func:`circular_stats`): the mean direction of the unit vectors
``(cos h, sin h)`` and the circular standard deviation ``sqrt(-2 ln R)`` (R = mean resultant length),
converted to degrees. For a concentrated sample this equals the linear standard deviation; for samples
straddling 0°/360° it stays small where a linear standard deviation would blow up to ~180°.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from tracker.geometry.parts import PRESET_COLORS

KAPPA = 2.5
"""Range half-width in standard deviations (thesis κ ≈ 2.5)."""

MIN_SIGMA_H_DEG = 2.0
"""Floor on the hue standard deviation used by calibration (degrees): a flat synthetic colour would
otherwise give a zero-width range that misses its own shaded pixels."""

MIN_SIGMA_SV = 0.03
"""Floor on the S and V standard deviations used by calibration (fractions)."""


def _wrap(h: float) -> float:
    return float(h) % 360.0


@dataclass(frozen=True)
class HSVRange:
    """A box in HSV space: hue interval in degrees (may wrap), S and V intervals as fractions in [0, 1]."""

    h_lo_deg: float
    h_hi_deg: float
    s_lo: float = 0.0
    s_hi: float = 1.0
    v_lo: float = 0.0
    v_hi: float = 1.0

    def __post_init__(self) -> None:
        vals = (self.h_lo_deg, self.h_hi_deg, self.s_lo, self.s_hi, self.v_lo, self.v_hi)
        if not all(isinstance(v, int | float | np.floating | np.integer) and math.isfinite(v) for v in vals):
            raise ValueError(f"HSVRange: all bounds must be finite numbers, got {vals}")
        if not (0.0 <= self.h_lo_deg <= 360.0 and 0.0 <= self.h_hi_deg <= 360.0):
            raise ValueError(
                f"HSVRange: hue bounds must be degrees in [0, 360], got {self.h_lo_deg}, {self.h_hi_deg}"
            )
        for lo, hi, what in ((self.s_lo, self.s_hi, "saturation"), (self.v_lo, self.v_hi, "value")):
            if not (0.0 <= lo <= hi <= 1.0):
                raise ValueError(
                    f"HSVRange: {what} bounds must satisfy 0 <= lo <= hi <= 1 (fractions, not 0-255), got {lo}, {hi}"
                )
        for name in ("h_lo_deg", "h_hi_deg", "s_lo", "s_hi", "v_lo", "v_hi"):
            object.__setattr__(self, name, float(getattr(self, name)))

    # ------------------------------------------------------------------ properties
    @property
    def wraps(self) -> bool:
        """True when the hue interval crosses 0°/360°."""
        return self.h_lo_deg > self.h_hi_deg

    @property
    def full_hue(self) -> bool:
        return not self.wraps and self.h_lo_deg <= 0.0 and self.h_hi_deg >= 360.0

    @property
    def hue_width_deg(self) -> float:
        return (360.0 - self.h_lo_deg + self.h_hi_deg) if self.wraps else (self.h_hi_deg - self.h_lo_deg)

    @property
    def hue_center_deg(self) -> float:
        return _wrap(self.h_lo_deg + self.hue_width_deg / 2.0)

    def contains(self, h_deg, s, v) -> np.ndarray:
        """Element-wise membership of float HSV samples (hue degrees, S and V fractions)."""
        h = np.mod(np.asarray(h_deg, dtype=np.float64), 360.0)
        s = np.asarray(s, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        if self.full_hue:
            in_h = np.ones(np.broadcast(h, s, v).shape, bool)
        elif self.wraps:
            in_h = (h >= self.h_lo_deg) | (h <= self.h_hi_deg)
        else:
            in_h = (h >= self.h_lo_deg) & (h <= self.h_hi_deg)
        return in_h & (s >= self.s_lo) & (s <= self.s_hi) & (v >= self.v_lo) & (v <= self.v_hi)

    # ------------------------------------------------------------------ OpenCV
    def opencv_bounds(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``[(lower, upper), ...]`` uint8 bounds for ``cv2.inRange`` on an OpenCV 8-bit HSV image.

        Hue degrees are halved (OpenCV H = h/2 in 0..179); bounds are rounded outwards so that the 8-bit range
        contains every pixel of the float range. A wrapping range gives two intervals.
        """
        s_lo, s_hi = int(math.floor(self.s_lo * 255.0 + 1e-9)), int(math.ceil(self.s_hi * 255.0 - 1e-9))
        v_lo, v_hi = int(math.floor(self.v_lo * 255.0 + 1e-9)), int(math.ceil(self.v_hi * 255.0 - 1e-9))

        def b(h0: int, h1: int) -> tuple[np.ndarray, np.ndarray]:
            return np.array([h0, s_lo, v_lo], np.uint8), np.array([h1, s_hi, v_hi], np.uint8)

        if self.full_hue:
            return [b(0, 179)]
        # OpenCV rounds h/2 to the nearest integer (and 359.5° → 180 → 0).
        h_lo8 = int(math.floor(self.h_lo_deg / 2.0))
        h_hi8 = int(math.ceil(self.h_hi_deg / 2.0))
        if self.wraps:
            out = [b(min(h_lo8, 179), 179)]
            out.append(b(0, min(h_hi8, 179)))
            return out
        if h_hi8 >= 180:  # touches 360°, which OpenCV stores as 0
            return [b(min(h_lo8, 179), 179), b(0, min(h_hi8 - 180, 179))]
        return [b(h_lo8, h_hi8)]

    def mask(self, hsv_u8: np.ndarray) -> np.ndarray:
        """uint8 mask (255 inside) of an OpenCV 8-bit HSV image (``cv2.COLOR_RGB2HSV`` of an RGB uint8 image)."""
        if not isinstance(hsv_u8, np.ndarray) or hsv_u8.ndim != 3 or hsv_u8.shape[2] != 3 or hsv_u8.dtype != np.uint8:
            raise ValueError(
                f"HSVRange.mask: expected an HxWx3 uint8 OpenCV HSV image, got "
                f"{getattr(hsv_u8, 'shape', None)} {getattr(hsv_u8, 'dtype', type(hsv_u8).__name__)}"
            )
        bounds = self.opencv_bounds()
        m = cv2.inRange(hsv_u8, bounds[0][0], bounds[0][1])
        for lo, hi in bounds[1:]:
            m = cv2.bitwise_or(m, cv2.inRange(hsv_u8, lo, hi))
        return m

    @staticmethod
    def from_opencv(lower, upper) -> HSVRange:
        """Range from OpenCV-convention bounds (H 0–179, S and V 0–255), e.g. from a colours.yaml file.

        ``lower[0] > upper[0]`` means a wrapping hue interval.
        """
        lo = [float(x) for x in lower]
        hi = [float(x) for x in upper]
        if len(lo) != 3 or len(hi) != 3:
            raise ValueError(f"HSVRange.from_opencv: bounds need 3 values each, got {lower}, {upper}")
        h_hi = min(360.0, 2.0 * hi[0] + (1.0 if hi[0] >= 179 else 0.0))
        return HSVRange(min(2.0 * lo[0], 360.0), h_hi, lo[1] / 255.0, hi[1] / 255.0, lo[2] / 255.0, hi[2] / 255.0)

    # ------------------------------------------------------------------ construction
    @staticmethod
    def from_center(
        h_center_deg: float, h_halfwidth_deg: float, s_lo: float, s_hi: float, v_lo: float, v_hi: float
    ) -> HSVRange:
        """Range of hues ``h_center ± h_halfwidth`` (wrapping as needed); half-width ≥ 180° gives all hues."""
        s_lo, s_hi = float(np.clip(s_lo, 0, 1)), float(np.clip(s_hi, 0, 1))
        v_lo, v_hi = float(np.clip(v_lo, 0, 1)), float(np.clip(v_hi, 0, 1))
        if h_halfwidth_deg >= 180.0:
            return HSVRange(0.0, 360.0, s_lo, s_hi, v_lo, v_hi)
        lo = _wrap(h_center_deg - h_halfwidth_deg)
        hi = _wrap(h_center_deg + h_halfwidth_deg)
        return HSVRange(lo, hi, s_lo, s_hi, v_lo, v_hi)

    @staticmethod
    def from_samples(h_deg: np.ndarray, s: np.ndarray, v: np.ndarray, kappa: float = KAPPA) -> HSVRange:
        """Calibrated range (eqs 3.4–3.6, corrected): mean ± κσ per channel, hue statistics circular.

        σ is floored at :data:`MIN_SIGMA_H_DEG` (hue) and :data:`MIN_SIGMA_SV` (S, V).
        """
        h_deg = np.asarray(h_deg, np.float64).ravel()
        s = np.asarray(s, np.float64).ravel()
        v = np.asarray(v, np.float64).ravel()
        if h_deg.size == 0:
            raise ValueError("HSVRange.from_samples: no samples")
        if not kappa > 0:
            raise ValueError(f"HSVRange.from_samples: kappa must be positive, got {kappa}")
        mu_h, sd_h = circular_stats(h_deg)
        sd_h = max(sd_h, MIN_SIGMA_H_DEG)
        mu_s, sd_s = float(s.mean()), max(float(s.std()), MIN_SIGMA_SV)
        mu_v, sd_v = float(v.mean()), max(float(v.std()), MIN_SIGMA_SV)
        return HSVRange.from_center(
            mu_h, kappa * sd_h, mu_s - kappa * sd_s, mu_s + kappa * sd_s, mu_v - kappa * sd_v, mu_v + kappa * sd_v
        )

    @staticmethod
    def preset(
        rgb: tuple[int, int, int],
        h_halfwidth_deg: float = 14.0,
        s_min_factor: float = 0.7,
        s_floor: float = 0.3,
        v_lo: float = 0.12,
    ) -> HSVRange:
        """Preset range around a nominal RGB colour (0–255).

        Hue: nominal hue ± ``h_halfwidth_deg``. Saturation: from ``max(s_floor, s_min_factor · S_nominal)`` to 1
        (shading keeps the saturation of a Lambertian surface; 0.7 × nominal keeps a wooden table, S ≈ 0.5 at
        the orange hue in the simulator and in real rooms, and the skin of the hand, S ≈ 0.4, out of the orange and
        red ranges, while real camera pixels of saturated parts stay above it). Value: from ``v_lo`` to 1 (shaded
        faces are dark; below ~0.12 the hue of real camera pixels is noise).
        """
        h, s, _ = rgb_to_hsv_float(np.asarray(rgb, np.float64).reshape(1, 3))[0]
        s_lo = max(s_floor, s_min_factor * s)
        return HSVRange.from_center(h, h_halfwidth_deg, s_lo, 1.0, v_lo, 1.0)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> HSVRange:
        try:
            return HSVRange(
                float(d["h_lo_deg"]),
                float(d["h_hi_deg"]),
                float(d.get("s_lo", 0.0)),
                float(d.get("s_hi", 1.0)),
                float(d.get("v_lo", 0.0)),
                float(d.get("v_hi", 1.0)),
            )
        except KeyError as exc:
            raise ValueError(f"HSV range: missing field {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise ValueError(f"HSV range {d!r}: {exc}") from exc


def circular_stats(h_deg: np.ndarray) -> tuple[float, float]:
    """Circular mean (degrees in [0, 360)) and circular standard deviation ``sqrt(-2 ln R)`` (degrees)."""
    a = np.deg2rad(np.asarray(h_deg, np.float64).ravel())
    if a.size == 0:
        raise ValueError("circular_stats: no samples")
    c, s = float(np.cos(a).mean()), float(np.sin(a).mean())
    r = math.hypot(c, s)
    mean = _wrap(math.degrees(math.atan2(s, c)))
    if r <= 1e-12:
        return mean, 180.0
    sd = math.degrees(math.sqrt(max(0.0, -2.0 * math.log(min(r, 1.0)))))
    return mean, sd


def rgb_to_hsv_float(rgb: np.ndarray) -> np.ndarray:
    """Eqs 3.1–3.3: RGB (0–255, any shape ``[..., 3]``) → HSV with H in degrees [0, 360), S and V in [0, 1]."""
    x = np.asarray(rgb, np.float32) / 255.0
    shape = x.shape
    hsv = cv2.cvtColor(x.reshape(-1, 1, 3), cv2.COLOR_RGB2HSV).reshape(shape)
    hsv[..., 0] = np.mod(hsv[..., 0], 360.0)
    return hsv


def preset_range(color: str | tuple[int, int, int], **kwargs) -> HSVRange:
    """Preset range of a colour name from :data:`tracker.geometry.parts.PRESET_COLORS` or of an RGB triple."""
    if isinstance(color, str):
        if color not in PRESET_COLORS:
            raise ValueError(f"unknown colour name {color!r}; known: {', '.join(PRESET_COLORS)}")
        color = PRESET_COLORS[color]
    return HSVRange.preset(tuple(int(c) for c in color), **kwargs)


PRESET_RANGES: dict[str, HSVRange] = {name: preset_range(name) for name in PRESET_COLORS}
"""Default ranges of the preset colour names (hue ± 14°; see :meth:`HSVRange.preset`)."""
