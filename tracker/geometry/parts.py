"""Descriptions of rigid parts: name, shape (box or mesh) and colour.

A box part's origin is its centre and its axes run along its edges; ``size`` is the full edge length
along x, y, z in metres. A mesh part's vertices are in metres in its own body frame after ``scale``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

CUBE_EDGE = 0.036
"""Edge of the seed's cubes, metres."""

ROD_SIZE = (0.02, 0.02, 0.10)
"""The optional rod part, metres."""

PRESET_COLORS: dict[str, tuple[int, int, int]] = {
    "red": (210, 30, 35),
    "green": (40, 170, 60),
    "blue": (35, 70, 200),
    "yellow": (235, 205, 30),
    "orange": (240, 120, 20),
    "purple": (130, 50, 170),
    "cyan": (30, 180, 200),
    "pink": (235, 110, 170),
}
"""Nominal RGB of the simulator's part colours (and of the colour-detection presets)."""


@dataclass(frozen=True)
class PartSpec:
    """A rigid part.

    * ``name``: unique name.
    * ``box``: full edge lengths (sx, sy, sz) in metres, or ``None`` for a mesh part.
    * ``mesh``: path to an OBJ/PLY/STL file (loaded with trimesh), or ``None`` for a box.
    * ``mesh_scale``: factor applied to mesh vertices to get metres.
    * ``color``: nominal RGB 0–255, or ``None`` when the part has no distinctive colour (depth only).
    """

    name: str
    box: tuple[float, float, float] | None = (CUBE_EDGE, CUBE_EDGE, CUBE_EDGE)
    mesh: str | None = None
    mesh_scale: float = 1.0
    color: tuple[int, int, int] | None = None

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("part needs a name")
        if (self.box is None) == (self.mesh is None):
            raise ValueError(f"part {self.name!r}: give exactly one of box or mesh")
        if self.box is not None and (len(self.box) != 3 or min(self.box) <= 0):
            raise ValueError(f"part {self.name!r}: box size must be three positive lengths, got {self.box}")

    @staticmethod
    def cube(name: str, color: str | tuple[int, int, int] | None = None, edge: float = CUBE_EDGE) -> PartSpec:
        rgb = PRESET_COLORS[color] if isinstance(color, str) else color
        return PartSpec(name=name, box=(edge, edge, edge), color=rgb)

    @property
    def is_cube(self) -> bool:
        return self.box is not None and np.ptp(self.box) < 1e-9

    def vertices(self) -> np.ndarray:
        """Body-frame vertices ``[N, 3]`` in metres (8 corners for a box)."""
        if self.box is not None:
            h = np.asarray(self.box) / 2.0
            signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
            return signs * h
        return self.load_mesh().vertices.copy()

    def load_mesh(self):
        """The part as a ``trimesh.Trimesh`` in metres (a box is built on the fly)."""
        import trimesh

        if self.box is not None:
            return trimesh.creation.box(extents=self.box)
        path = Path(self.mesh)
        if not path.is_file():
            raise FileNotFoundError(f"part {self.name!r}: mesh file not found: {path}")
        mesh = trimesh.load(path, force="mesh")
        mesh.apply_scale(self.mesh_scale)
        return mesh

    def bounding_radius(self) -> float:
        """Radius of the smallest origin-centred sphere containing the part, metres."""
        return float(np.linalg.norm(self.vertices(), axis=1).max())
