"""Skin colours of the simulated hands, drawn from real labelled skin pixels.

Source: the UCI Skin Segmentation data set (Bhatt & Dhall 2012, CC BY 4.0), read at run time from the shared
folder (``tracker.shared_data.skin_data_path()``; it is not in the repository). A hand's colour is one skin
pixel drawn at random among the skin rows whose luma Y lies in [60, 230] (the extremes are dark shadows and
specular highlights of studio faces, not skin tones).

Fallback when the shared folder is absent (fresh clone): :data:`BUILTIN_TONES`, six tones from light to dark
(the first is the simulator's original palm colour), one drawn uniformly and jittered by ±6 % per channel.
Frames of the hand scenarios therefore differ between a checkout with and without the shared data; the data
source used is reported by :func:`skin_source`, and the first fallback draw warns (``UserWarning``, once per
process): a checkout whose ``../shared`` does not exist (e.g. a git worktree elsewhere) renders other hands than the
main checkout unless ``$ASSEMBLY_AGENT_SHARED`` is set. (In session 23 such a worktree's ``hands-s3`` tuning seed 0
drew a jittered built-in tone at (Cr, Cb) ≈ (141, 104), outside the skin model at log τ = −2: no hand pixel in the
colour mask; with the real data the same seed's hand is 97 % inside it.)
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tracker.shared_data import skin_data_path

BUILTIN_TONES: tuple[tuple[float, float, float], ...] = (
    (226.0, 176.0, 146.0),
    (236.0, 188.0, 150.0),
    (214.0, 160.0, 118.0),
    (190.0, 132.0, 92.0),
    (150.0, 100.0, 70.0),
    (112.0, 74.0, 52.0),
)
"""Built-in skin tones (RGB, 0..255), used only when the real skin data is not available."""

SHADE = 0.85
"""Typical shading factor (ambient + diffuse·cos) of a hand under the simulator's light: the albedo is the
observed skin colour divided by it, so that the rendered colour is close to the sampled one."""


@lru_cache(maxsize=1)
def _skin_rgb() -> np.ndarray | None:
    """Real skin colours (RGB float [N, 3]) with luma in [60, 230], or None without the shared data."""
    path = skin_data_path()
    if not path.is_file():
        return None
    with np.load(path) as z:
        bgr = np.asarray(z["bgr"], np.float64)
        label = np.asarray(z["label"])
    rgb = bgr[label == 1][:, ::-1]
    y = rgb @ np.array([0.299, 0.587, 0.114])
    return rgb[(y >= 60.0) & (y <= 230.0)]


def skin_source() -> str:
    """``"uci-skin"`` when hands are coloured from the real data, ``"builtin"`` otherwise."""
    return "uci-skin" if _skin_rgb() is not None else "builtin"


@lru_cache(maxsize=1)
def _warn_builtin() -> None:
    """Warn once that hands are coloured from the built-in tones."""
    import warnings

    warnings.warn(f"simulated hands: no skin data at {skin_data_path()}; using the built-in skin tones (the frames "
                  "differ from a checkout with the shared data; set ASSEMBLY_AGENT_SHARED)", stacklevel=3)  # fmt: skip


def draw_skin_tone(rng: np.random.Generator) -> np.ndarray:
    """One observed skin colour (RGB 0..255) drawn from the real data (or the built-in fallback)."""
    data = _skin_rgb()
    if data is not None and len(data):
        return data[int(rng.integers(len(data)))].copy()
    _warn_builtin()
    tone = np.asarray(BUILTIN_TONES[int(rng.integers(len(BUILTIN_TONES)))], float)
    return np.clip(tone * rng.uniform(0.94, 1.06, size=3), 0.0, 255.0)


def hand_albedos(rng: np.random.Generator) -> tuple[tuple[float, float, float], ...]:
    """Albedos (palm, fingers, forearm) of one hand: a drawn skin tone, fingers and forearm slightly darker.

    The palm albedo is the tone divided by :data:`SHADE`, scaled down as a whole where a channel would exceed 255 (so
    that the rendered colour keeps the tone's hue; clipping each channel, as before session 23, cut the red channel of
    half the real tones — 52 % have a channel above 255·SHADE — and rendered bright tones pale and yellow, outside the
    skin region: tuning seed 2 of ``hands-s3`` drew (249, 196, 178), (Cr, Cb) (156, 110), and was rendered at (139,
    116), where the skin model's log ratio lies below −2 for most of the hand)."""
    base = draw_skin_tone(rng) / SHADE
    base = base * min(1.0, 255.0 / max(float(base.max()), 1e-9))
    return tuple(tuple(float(c) for c in np.clip(base * f, 0.0, 255.0)) for f in (1.0, 0.965, 0.92))  # type: ignore[return-value]
