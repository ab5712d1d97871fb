"""RGB-D frames in shared memory: the layout a parent and its child processes share (the simulator's frame source,
the hand process, the fused odometry's camera path).

A block of ``count`` slots, each an H×W×3 ``uint8`` colour image followed by an H×W ``float32`` depth image
(metres, NaN = missing), packed one after the other; :func:`frame_bytes` is one slot's size.
"""

from __future__ import annotations

from multiprocessing.shared_memory import SharedMemory

import numpy as np


def frame_bytes(height: int, width: int) -> int:
    """Bytes of one frame slot: colour (3 per pixel) and depth (4 per pixel)."""
    return height * width * 7


def frame_slots(shm: SharedMemory, count: int, height: int, width: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``count`` (colour, depth) slots laid out in ``shm`` (arrays viewing its buffer, not copies)."""
    size, n_color = frame_bytes(height, width), height * width * 3
    return [(np.ndarray((height, width, 3), np.uint8, buffer=shm.buf, offset=k * size),
             np.ndarray((height, width), np.float32, buffer=shm.buf, offset=k * size + n_color))
            for k in range(count)]  # fmt: skip
