"""Skin colour model: GMMs on the (Cr, Cb) chrominance and the likelihood-ratio test (hand-tracking spec §3.1, §7,
§14.1).

Colours are 8-bit YCrCb as OpenCV computes them (``cv2.COLOR_RGB2YCrCb``); a feature is the pair (Cr, Cb) — the
spec's (Cb, Cr) in OpenCV's channel order. A pixel is skin (ω1) when
``log p(c | skin) − log p(c | background) > log τ`` (eq. 3.22). The test is precomputed as a 256×256 boolean
lookup table over (Cr, Cb), so a frame's mask is one table lookup.

* Skin model: 2-component full-covariance GMM (thesis §7.1), fitted on the real labelled skin pixels of the
  UCI Skin Segmentation data (``scripts/fit_skin_model.py`` writes ``skin_model.json`` beside this module; the
  file ships in the repository, so nothing is fitted at start-up and a fresh clone works without ../shared).
* Background model ω2: ``skin_model.json`` carries a generic non-skin GMM (the same data's non-skin pixels);
  :meth:`SkinModel.with_background` replaces it by a GMM of the session's own hand-free frame (table and parts,
  spec §14.1; 4 components), mixed with a uniform floor of weight :data:`UNIFORM_FLOOR` so that colours seen in
  neither model fall back to the thesis's uniform ω2.
* Per-session adaptation: :meth:`SkinModel.adapted` moves the skin GMM's means towards the colours of tracked
  hand pixels (MAP adaptation of the means, Reynolds et al. 2000, relevance factor 16), each mean by a bounded
  Mahalanobis distance from the unadapted model.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numba as nb
import numpy as np

MODEL_PATH = Path(__file__).with_name("skin_model.json")
"""The shipped model (written by ``scripts/fit_skin_model.py``)."""

UNIFORM_FLOOR = 0.2
"""Weight of the uniform density (1/256² per (Cr, Cb) cell) in a session background model."""

_GRID = np.stack(np.meshgrid(np.arange(256.0), np.arange(256.0), indexing="ij"), axis=-1).reshape(-1, 2)
"""All 8-bit (Cr, Cb) pairs, row-major in Cr (index = 256·Cr + Cb)."""


@dataclass(frozen=True)
class Gmm2D:
    """A 2-D Gaussian mixture: ``weights`` [K], ``means`` [K, 2], ``covs`` [K, 2, 2] (full), on (Cr, Cb)."""

    weights: np.ndarray
    means: np.ndarray
    covs: np.ndarray

    @staticmethod
    def fit(x: np.ndarray, k: int, seed: int = 0, max_samples: int = 60000) -> Gmm2D:
        """EM fit (scikit-learn GaussianMixture, full covariances, k-means initialisation) on ``x`` [N, 2]; at
        most ``max_samples`` rows (a seeded random subsample) are used, and at most as many components as there are
        distinct rows."""
        from sklearn.mixture import GaussianMixture

        x = np.asarray(x, np.float64).reshape(-1, 2)
        if len(x) > max_samples:
            x = x[np.random.default_rng(seed).choice(len(x), max_samples, replace=False)]
        k = max(1, min(int(k), len(np.unique(x, axis=0))))  # no more components than distinct colours (a uniform
        # frame has one): k-means would otherwise warn that it found fewer clusters than asked
        g = GaussianMixture(k, covariance_type="full", random_state=seed, reg_covar=1e-3).fit(x)
        return Gmm2D(g.weights_.copy(), g.means_.copy(), g.covariances_.copy())

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """log density at the rows of ``x`` [N, 2]."""
        x = np.asarray(x, np.float64).reshape(-1, 2)
        out = np.full(len(x), -np.inf)
        for w, m, c in zip(self.weights, self.means, self.covs, strict=True):
            det = c[0, 0] * c[1, 1] - c[0, 1] * c[1, 0]
            inv = np.array([[c[1, 1], -c[0, 1]], [-c[1, 0], c[0, 0]]]) / det
            d = x - m
            q = d[:, 0] * (inv[0, 0] * d[:, 0] + inv[0, 1] * d[:, 1])
            q = q + d[:, 1] * (inv[1, 0] * d[:, 0] + inv[1, 1] * d[:, 1])
            out = np.logaddexp(out, np.log(w) - np.log(2 * np.pi) - 0.5 * np.log(det) - 0.5 * q)
        return out

    def grid_logpdf(self) -> np.ndarray:
        """:meth:`logpdf` at every 8-bit (Cr, Cb) pair, in the order of ``_GRID`` (index 256·Cr + Cb): [65536].

        The same floating-point operations element by element, on a 256×256 broadcast instead of 65536 gathered rows
        (the values are bit-identical; about a third of the time). A first component's ``logaddexp`` with −inf is
        its own term (log1p(exp(−inf)) = 0)."""
        v = np.arange(256.0)
        out = None
        for w, m, c in zip(self.weights, self.means, self.covs, strict=True):
            det = c[0, 0] * c[1, 1] - c[0, 1] * c[1, 0]
            inv = np.array([[c[1, 1], -c[0, 1]], [-c[1, 0], c[0, 0]]]) / det
            d0 = (v - m[0])[:, None]
            d1 = (v - m[1])[None, :]
            q = d0 * (inv[0, 0] * d0 + inv[0, 1] * d1)
            q = q + d1 * (inv[1, 0] * d0 + inv[1, 1] * d1)
            term = np.log(w) - np.log(2 * np.pi) - 0.5 * np.log(det) - 0.5 * q
            out = term + 0.0 if out is None else np.logaddexp(out, term)
        return np.full(256 * 256, -np.inf) if out is None else out.reshape(-1)

    def map_adapt(self, x: np.ndarray, relevance: float = 16.0, max_shift: float | None = None) -> Gmm2D:
        """MAP adaptation of the means to the samples ``x`` [N, 2] (weights and covariances kept); ``max_shift``:
        no mean moves farther than this Mahalanobis distance (in its own component's covariance) from where it was
        (None: unbounded)."""
        x = np.asarray(x, np.float64).reshape(-1, 2)
        if len(x) == 0:
            return self
        logp = np.stack([np.log(w) + Gmm2D(np.ones(1), m[None], c[None]).logpdf(x)
                         for w, m, c in zip(self.weights, self.means, self.covs, strict=True)], axis=1)  # fmt: skip
        resp = np.exp(logp - logp.max(axis=1, keepdims=True))
        resp /= resp.sum(axis=1, keepdims=True)
        n = resp.sum(axis=0)
        ex = (resp.T @ x) / np.maximum(n, 1e-9)[:, None]
        a = (n / (n + relevance))[:, None]
        means = a * ex + (1 - a) * self.means
        if max_shift is not None:
            for j, c in enumerate(self.covs):
                d = means[j] - self.means[j]
                m = float(np.sqrt(max(d @ np.linalg.solve(c, d), 0.0)))
                if m > max_shift:
                    means[j] = self.means[j] + d * (max_shift / m)
        return Gmm2D(self.weights, means, self.covs)

    def to_dict(self) -> dict:
        return {"weights": self.weights.tolist(), "means": self.means.tolist(), "covs": self.covs.tolist()}

    @staticmethod
    def from_dict(d: dict) -> Gmm2D:
        g = Gmm2D(np.asarray(d["weights"], float), np.asarray(d["means"], float), np.asarray(d["covs"], float))
        if g.means.shape != (len(g.weights), 2) or g.covs.shape != (len(g.weights), 2, 2):
            raise ValueError("skin model: a GMM needs weights [K], means [K, 2] and covs [K, 2, 2]")
        return g


def crcb(rgb: np.ndarray) -> np.ndarray:
    """(Cr, Cb) uint8 [..., 2] of 8-bit RGB pixels [..., 3]."""
    rgb = np.ascontiguousarray(rgb, np.uint8)
    flat = rgb.reshape(-1, 1, 3)
    return cv2.cvtColor(flat, cv2.COLOR_RGB2YCrCb)[:, 0, 1:].reshape(rgb.shape[:-1] + (2,))


class SkinModel:
    """Skin / background GMMs and the LRT threshold ``log_tau``; :meth:`mask` classifies an RGB image.

    ``background`` None means the uniform ω2 of the thesis; ``floor`` is the weight of a uniform density mixed into
    the background model (0 for the generic model, :data:`UNIFORM_FLOOR` for a session model).
    """

    def __init__(self, skin: Gmm2D, background: Gmm2D | None, log_tau: float = 0.0, floor: float = 0.0,
                 info: dict | None = None, _ls: np.ndarray | None = None,
                 _lb: np.ndarray | None = None) -> None:  # fmt: skip
        self.skin = skin
        self.background = background
        self.log_tau = float(log_tau)
        self.floor = float(floor)
        self.info = dict(info or {})
        ls = skin.grid_logpdf() if _ls is None else _ls
        if _lb is not None:
            lb = _lb
        elif background is None:
            lb = np.full(len(_GRID), -np.log(256.0 * 256.0))
        else:
            lb = background.grid_logpdf()
            if self.floor > 0:
                lb = np.logaddexp(np.log1p(-self.floor) + lb, np.log(self.floor) - np.log(256.0 * 256.0))
        self._ls, self._lb = ls, lb
        self.log_ratio = (ls - lb).reshape(256, 256)
        """log p(c|skin) − log p(c|background) per (Cr, Cb)."""
        self.lut = (self.log_ratio > self.log_tau).astype(np.uint8)
        """1 where (Cr, Cb) is skin: ``lut[Cr, Cb]``."""

    # ------------------------------------------------------------------ classification
    def classify(self, cr_cb: np.ndarray) -> np.ndarray:
        """uint8 0/1 skin labels of (Cr, Cb) uint8 pairs [..., 2]."""
        c = np.asarray(cr_cb, np.uint8)
        return self.lut[c[..., 0], c[..., 1]]

    def mask(self, rgb: np.ndarray) -> np.ndarray:
        """Colour mask B^c (uint8 0/1, H×W) of an 8-bit RGB image."""
        ycc = cv2.cvtColor(np.ascontiguousarray(rgb, np.uint8), cv2.COLOR_RGB2YCrCb)
        out = np.empty(ycc.shape[:2], np.uint8)
        _lookup(ycc, self.lut, out)
        return out

    # ------------------------------------------------------------------ session
    def with_background(self, rgb: np.ndarray, k: int = 4, step: int = 4, seed: int = 0,
                        keep: np.ndarray | None = None) -> SkinModel:  # fmt: skip
        """This model with ω2 fitted on a hand-free RGB frame (every ``step``-th pixel in both directions); ``keep``
        (bool H×W): fit only those pixels (the others are excluded from the colour mask anyway). Unchanged when
        fewer than 50·k pixels remain."""
        x = crcb(np.asarray(rgb)[::step, ::step]).reshape(-1, 2)
        if keep is not None:
            x = x[np.asarray(keep, bool)[::step, ::step].reshape(-1)]
            if len(x) < 50 * k:
                return self
        bg = Gmm2D.fit(x, k, seed=seed)
        return SkinModel(self.skin, bg, self.log_tau, UNIFORM_FLOOR, {**self.info, "background": "session"},
                         _ls=self._ls)  # fmt: skip

    def adapted(self, skin_rgb: np.ndarray, relevance: float = 16.0, max_shift: float | None = None) -> SkinModel:
        """This model with the skin means MAP-adapted to the RGB pixels ``skin_rgb`` [N, 3], each mean moving at most
        ``max_shift`` Mahalanobis units (None: unbounded). Adapt from the session's unadapted model each time (not from
        the last adapted one), so that the shifts do not add up."""
        x = crcb(np.asarray(skin_rgb, np.uint8).reshape(-1, 1, 3)).reshape(-1, 2)
        return SkinModel(self.skin.map_adapt(x, relevance, max_shift), self.background, self.log_tau, self.floor,
                         self.info, _lb=self._lb)  # fmt: skip

    def with_threshold(self, log_tau: float) -> SkinModel:
        return SkinModel(self.skin, self.background, log_tau, self.floor, self.info, _ls=self._ls, _lb=self._lb)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {
            "skin": self.skin.to_dict(),
            "background": None if self.background is None else self.background.to_dict(),
            "log_tau": self.log_tau,
            "floor": self.floor,
            "info": self.info,
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")

    @staticmethod
    def load(path: str | Path = MODEL_PATH) -> SkinModel:
        """Read a model written by :meth:`save`; ``ValueError`` naming the file if it is malformed."""
        try:
            d = json.loads(Path(path).read_text())
            bg = d.get("background")
            return SkinModel(Gmm2D.from_dict(d["skin"]), None if bg is None else Gmm2D.from_dict(bg),
                             float(d.get("log_tau", 0.0)), float(d.get("floor", 0.0)), d.get("info"))  # fmt: skip
        except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path}: not a skin model file ({exc})") from exc


@nb.njit(cache=True, nogil=True)
def _lookup(ycc, lut, out):
    """``out[i, j] = lut[Cr, Cb]`` of the YCrCb image ``ycc`` [H, W, 3] (uint8)."""
    for i in range(ycc.shape[0]):
        for j in range(ycc.shape[1]):
            out[i, j] = lut[ycc[i, j, 1], ycc[i, j, 2]]
