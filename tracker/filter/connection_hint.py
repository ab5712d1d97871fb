"""What the assembly monitor tells the tracker about connections (spec sections 9–10, Algorithm 6)."""

from __future__ import annotations

from dataclasses import dataclass

from tracker.geometry.pose import Pose


@dataclass(frozen=True)
class ConnectionHint:
    """A connection that is complete or near completion.

    * ``first``, ``second``: part names.
    * ``relative``: pose of ``second`` in ``first``'s body frame, already expressed in the tracker's own
      part frames (i.e. with the cube-symmetry choice applied: p = Q_aᵀ p_des, R = Q_aᵀ R_des Q_b).
    * ``n_particles``: N_k, the number of leading particles forced to satisfy the connection.
    * ``locked``: the connection is established (completed); ``n_particles`` is then N_max.
    """

    first: str
    second: str
    relative: Pose
    n_particles: int
    locked: bool = False
