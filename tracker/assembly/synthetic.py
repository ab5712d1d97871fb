"""Synthetic poses of structures on a table, for tests and for the evaluation's fallback pose source.

Frames: a structure frame (see :mod:`tracker.assembly.part_graph`) is placed on the table frame (y up,
resting on the table) with a heading ``yaw`` about the table normal, then mapped into the camera frame.
Cubes may be given a random one of their 24 indistinguishable orientations (as the simulator does).
"""

from __future__ import annotations

import numpy as np

from tracker.assembly.part_graph import PartGraph
from tracker.geometry.parts import CUBE_EDGE
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import cube_group


def default_table_to_camera(distance: float = 0.6, pitch_deg: float = 50.0) -> Pose:
    """Table frame → camera frame for a camera ``distance`` metres from the table origin, looking down by
    ``pitch_deg`` towards the table, camera x = table x."""
    th = np.radians(pitch_deg)
    x_c = np.array([1.0, 0.0, 0.0])
    z_c = np.array([0.0, -np.sin(th), -np.cos(th)])
    y_c = np.cross(z_c, x_c)
    R_ct = np.stack([x_c, y_c, z_c], axis=1)  # camera axes in table coordinates (camera → table)
    origin = -distance * z_c
    camera_to_table = Pose.from_rt(R_ct, origin)
    return camera_to_table.inverse()


def yaw_pose(yaw: float, t: np.ndarray) -> Pose:
    """Rotation by ``yaw`` about the table's y axis, then translation ``t`` (table frame)."""
    return Pose.from_rotvec(np.array([0.0, yaw, 0.0]), np.asarray(t, float))


def place_structure(
    graph: PartGraph,
    table_to_camera: Pose,
    xz: tuple[float, float] = (0.0, 0.0),
    yaw: float = 0.0,
    edge: float = CUBE_EDGE,
    rng: np.random.Generator | None = None,
    parts: list[str] | None = None,
) -> dict[str, Pose]:
    """Camera-frame poses of the (sub-)structure ``parts`` (default all) resting on the table.

    With ``rng`` each cube gets a random cube-group orientation ``R_fund · S``.
    """
    layout = graph.layout()
    names = parts or list(layout)
    lo = min(layout[p].t[1] for p in names)
    base = yaw_pose(yaw, np.array([xz[0], edge / 2.0 - lo, xz[1]]))
    G = cube_group()
    out = {}
    for p in names:
        pose = table_to_camera @ base @ layout[p]
        if rng is not None:
            S = G[int(rng.integers(len(G)))]
            pose = Pose.from_rt(pose.R @ S, pose.t)
        out[p] = pose
    return out


def jitter(poses: dict[str, Pose], rng: np.random.Generator, sigma_t: float = 0.002, sigma_r: float = 0.03
           ) -> dict[str, Pose]:
    """Poses with Gaussian noise: ``sigma_t`` metres per axis, ``sigma_r`` radians rotation vector per axis."""
    out = {}
    for n, p in poses.items():
        dR = Pose.from_rotvec(rng.normal(0.0, sigma_r, 3), np.zeros(3)).R
        out[n] = Pose.from_rt(p.R @ dR, p.t + rng.normal(0.0, sigma_t, 3))
    return out


def build_up_session(
    graph: PartGraph,
    order: list[str],
    table_to_camera: Pose,
    rng: np.random.Generator,
    extra_parts: list[str] | None = None,
    frames_per_step: int = 5,
    dt: float = 0.1,
    noise: tuple[float, float] = (0.002, 0.03),
    yaw: float = 0.0,
    edge: float = CUBE_EDGE,
) -> list[tuple[float, dict[str, Pose], list[tuple[float, str, str]]]]:
    """A simple scripted session: parts join the structure one by one in ``order``.

    Returns ``[(t, noisy poses, true connection times so far)]``; parts not yet placed (and ``extra_parts``)
    lie apart on the table nearer the user. The connection time of a part is the first frame it is in place.
    """
    layout_all = place_structure(graph, table_to_camera, (0.0, -0.02), yaw, edge, rng)
    loose = [*order, *(extra_parts or [])]
    spots = {p: table_to_camera @ yaw_pose(0.0, np.array([-0.2 + 0.08 * i, edge / 2, 0.12]))
             for i, p in enumerate(loose)}
    frames = []
    placed: list[str] = []
    truth: list[tuple[float, str, str]] = []
    t = 0.0
    for p in order:
        placed.append(p)
        for c in graph.connections:
            if p in (c.first, c.second) and {c.first, c.second} <= set(placed) and len(placed) > 1:
                truth.append((t, c.first, c.second))
        for _ in range(frames_per_step):
            poses = {q: (layout_all[q] if q in placed else spots[q]) for q in loose}
            frames.append((t, jitter(poses, rng, *noise), list(truth)))
            t += dt
    return frames
