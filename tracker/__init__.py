"""Assembly Agent engine: perception, estimation and assembly reasoning.

Conventions used everywhere in this package:

* Lengths in metres, time in seconds, angles in radians unless a name says ``_deg``.
* Camera frame: x right, y down, z forward (OpenCV / Kinect convention).
* Quaternions are Hamilton, stored ``[x, y, z, w]`` (scalar last, scipy order).
* Images: colour is RGB ``uint8`` H×W×3; depth is ``float32`` metres H×W with NaN where missing.
"""

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

__all__ = ["Frame", "Intrinsics", "PartSpec", "Pose"]
