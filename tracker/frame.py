"""One RGB-D frame as it flows through the pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.geometry.camera import Intrinsics


class FrameError(ValueError):
    """A frame whose images do not match their description (shape, dtype, intrinsics)."""


@dataclass
class Frame:
    """An RGB-D frame.

    * ``index``: frame number in its source, from 0.
    * ``timestamp``: seconds since the source started.
    * ``color``: RGB ``uint8`` H×W×3.
    * ``depth``: metres, ``float32`` H×W, NaN where the sensor gave no measurement; registered to
      ``color`` (same pixel grid and intrinsics). ``None`` when the source has no depth.
    * ``intrinsics``: of the colour image (and the registered depth image).
    * ``meta``: free-form per-frame extras (e.g. ground truth from the simulator).
    """

    index: int
    timestamp: float
    color: np.ndarray
    depth: np.ndarray | None
    intrinsics: Intrinsics
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`FrameError` with a clear message if the frame is malformed."""
        c = self.color
        if not isinstance(c, np.ndarray) or c.ndim != 3 or c.shape[2] != 3 or c.dtype != np.uint8:
            desc = f"{getattr(c, 'shape', None)} {getattr(c, 'dtype', type(c).__name__)}"
            raise FrameError(f"frame {self.index}: colour must be uint8 HxWx3, got {desc}")
        h, w = c.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise FrameError(
                f"frame {self.index}: colour is {w}x{h} but intrinsics say "
                f"{self.intrinsics.width}x{self.intrinsics.height}"
            )
        d = self.depth
        if d is not None:
            if not isinstance(d, np.ndarray) or d.shape != (h, w):
                raise FrameError(
                    f"frame {self.index}: depth must be {h}x{w} to match colour, got {getattr(d, 'shape', None)}"
                )
            if d.dtype != np.float32:
                raise FrameError(f"frame {self.index}: depth must be float32 metres, got {d.dtype}")

    @property
    def has_depth(self) -> bool:
        d = self.depth  # (a sparse grid first: a frame with depth is answered without a full-image pass)
        return d is not None and (bool(np.isfinite(d[::16, ::16]).any()) or bool(np.isfinite(d).any()))
