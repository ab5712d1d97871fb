"""Assembly Agent engine: perception, estimation and assembly reasoning.

Conventions used everywhere in this package:

* Lengths in metres, time in seconds, angles in radians unless a name says ``_deg``.
* Camera frame: x right, y down, z forward (OpenCV / Kinect convention).
* Quaternions are Hamilton, stored ``[x, y, z, w]`` (scalar last, scipy order).
* Images: colour is RGB ``uint8`` H×W×3; depth is ``float32`` metres H×W with NaN where missing.
"""

from tracker import numba_cache

numba_cache.configure()  # before any kernel module is imported: a cache keyed by the kernels' source

from tracker.frame import Frame  # noqa: E402
from tracker.geometry.camera import Intrinsics  # noqa: E402
from tracker.geometry.parts import PartSpec  # noqa: E402
from tracker.geometry.pose import Pose  # noqa: E402

__all__ = ["Frame", "Intrinsics", "PartSpec", "Pose"]
