"""Scripted scenarios of the simulated table: target structures, cube layouts, hand passes and events.

A scenario script is a :class:`Timeline`: every part's rest poses over time (table frame), the hand's
passes (key frames of a smooth minimum-jerk path: reach in from the user's side, grasp, lift, carry,
lower, release, retract) and the connection events. Scripts are generated from a seeded
``numpy.random.Generator``, so a scenario with the same seed and options is always the same.

Structures are given in cube cells (units of the cube edge ``a``) in the structure frame: origin at the
first cube's centre, y up along the table normal, x running left→right for the user/camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.assembly.events import ConnectionEvent
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import CUBE_EDGE, PartSpec
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import cube_group

A = CUBE_EDGE


@dataclass(frozen=True)
class Structure:
    """A target structure: ``cells`` (part name, (i, j, k) in cube edges) in plan order and the planned
    ``connections`` (first, second) — the second's cell minus the first's is the connection offset."""

    name: str
    cells: tuple[tuple[str, tuple[int, int, int]], ...]
    connections: tuple[tuple[str, str], ...]

    def cell(self, name: str) -> tuple[int, int, int]:
        return dict(self.cells)[name]

    def positions(self, edge: float = A) -> dict[str, np.ndarray]:
        """Cube centres in the structure frame, metres."""
        return {n: np.asarray(c, float) * edge for n, c in self.cells}

    def offset(self, first: str, second: str, edge: float = A) -> np.ndarray:
        """Position of ``second`` relative to ``first`` in the structure frame, metres."""
        return (np.asarray(self.cell(second), float) - np.asarray(self.cell(first), float)) * edge

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "cells": {n: list(c) for n, c in self.cells},
            "connections": [list(c) for c in self.connections],
        }


def _row(names: tuple[str, ...]) -> Structure:
    cells = tuple((n, (i, 0, 0)) for i, n in enumerate(names))
    conns = tuple((names[i], names[i + 1]) for i in range(len(names) - 1))
    return Structure(f"row-{len(names)}", cells, conns)


GUIDANCE_TARGET = Structure(
    "guidance-target",
    (("red", (0, 0, 0)), ("green", (1, 0, 0)), ("blue", (2, 0, 0)), ("orange", (1, 0, 1)), ("yellow", (1, 1, 0))),
    (("red", "green"), ("green", "blue"), ("green", "orange"), ("green", "yellow")),
)
T_TOWER = Structure(
    "T-tower",
    (("red", (0, 0, 0)), ("green", (1, 0, 0)), ("blue", (2, 0, 0)), ("yellow", (1, 1, 0)), ("orange", (1, 2, 0))),
    (("red", "green"), ("green", "blue"), ("green", "yellow"), ("yellow", "orange")),
)
L_SHAPE = Structure(
    "L",
    (("red", (0, 0, 0)), ("green", (1, 0, 0)), ("blue", (2, 0, 0)), ("yellow", (2, 0, 1)), ("orange", (2, 0, 2))),
    (("red", "green"), ("green", "blue"), ("blue", "yellow"), ("yellow", "orange")),
)
TOWER_WINGS = Structure(
    "tower with wings",
    (("red", (0, 0, 0)), ("green", (0, 1, 0)), ("blue", (0, 2, 0)), ("yellow", (1, 0, 0)), ("orange", (-1, 0, 0))),
    (("red", "green"), ("green", "blue"), ("red", "yellow"), ("orange", "red")),
)

FIVE = ("red", "green", "blue", "yellow", "orange")


@dataclass(frozen=True)
class ScenarioInfo:
    """A scenario: ``name``, one-line ``description``, cube ``parts`` (colour names, also the part names),
    target ``structure`` (or None), build ``order`` ("plan", "random" or None) and ``distractors``."""

    name: str
    description: str
    parts: tuple[str, ...]
    structure: Structure | None = None
    order: str | None = None
    distractors: tuple[str, ...] = ()
    hands: str | None = None
    """Hand-tracking scenario style (``"s1"``, ``"s2"``, ``"s3"``; see :data:`HAND_STYLES`) or None."""

    def to_dict(self) -> dict:
        d = {
            "name": self.name,
            "description": self.description,
            "parts": list(self.parts),
            "structure": self.structure.to_dict() if self.structure else None,
            "order": self.order,
            "distractors": list(self.distractors),
        }
        if self.hands is not None:
            d["hands"] = self.hands
        return d


@dataclass(frozen=True)
class HandStyle:
    """How the hands of a hand-tracking scenario look and move (hand-tracking spec, section 14.9).

    ``n_hands`` 1 or 2; ``sleeves``: long sleeves (the forearm is cloth-coloured) or bare forearms (skin);
    ``motion_blur``: directional blur of the moving hands; ``overlap``: the second hand is sent close to (and
    above) the first one and both hands pass over the parts; ``speed``: factor on the hand speed;
    ``duration``: seconds of wandering (whatever the speed) between entering (1 s) and leaving (1.2 s); moves
    between key points take 0.8–1.6 s (÷ speed): at speed 1 the palm moves 5 px/frame (median) in the image,
    up to about 25 px/frame.
    """

    n_hands: int
    sleeves: bool
    motion_blur: bool
    overlap: bool
    speed: float = 1.0
    duration: float = 10.0


HAND_STYLES: dict[str, HandStyle] = {
    "s1": HandStyle(1, sleeves=True, motion_blur=False, overlap=False),
    "s2": HandStyle(2, sleeves=True, motion_blur=False, overlap=True),
    "s3": HandStyle(1, sleeves=False, motion_blur=True, overlap=True, speed=1.25),
}

SLEEVE_COLORS: tuple[tuple[float, float, float], ...] = ((45.0, 55.0, 95.0), (70.0, 70.0, 75.0), (30.0, 90.0, 70.0))
"""Long-sleeve cloth colours (RGB) of the hand scenarios S1 and S2."""

EXTRA_PART_COLORS: dict[str, tuple[int, int, int]] = {"wood": (192, 146, 98)}
"""Part colours of the hand scenarios that are not colour-detection presets (natural wood, skin-like)."""


SCENARIOS: dict[str, ScenarioInfo] = {
    s.name: s
    for s in (
        ScenarioInfo("static", "5 cubes at rest on the table, no hand (10 s by default)", FIVE),
        ScenarioInfo("free", "a hand picks and places the 5 cubes at random, making and breaking connections", FIVE),
        ScenarioInfo(
            "guidance-demo", "the guidance target (row of 3, one in front, one on top) built in plan order", FIVE,
            GUIDANCE_TARGET, "plan",
        ),
        ScenarioInfo("guess-1", "the 'T-tower' built in a random physically possible order", FIVE, T_TOWER, "random"),
        ScenarioInfo("guess-2", "the 'L' built in a random physically possible order", FIVE, L_SHAPE, "random"),
        ScenarioInfo(
            "guess-3", "the 'tower with wings' built in a random physically possible order", FIVE, TOWER_WINGS,
            "random",
        ),
        ScenarioInfo(
            "learning-4", "4 word cubes put in a row (orange, purple are distractors)",
            ("red", "green", "blue", "yellow", "orange", "purple"), _row(("red", "green", "blue", "yellow")),
            "random", ("orange", "purple"),
        ),
        ScenarioInfo(
            "learning-5", "5 word cubes put in a row (purple, cyan are distractors)",
            ("red", "green", "blue", "yellow", "orange", "purple", "cyan"), _row(FIVE), "random", ("purple", "cyan"),
        ),
        ScenarioInfo(
            "hands-s1", "hand tracking S1: one hand with a long sleeve wanders over 4 parts, no overlap (10 s)",
            ("green", "blue", "purple", "cyan"), hands="s1",
        ),
        ScenarioInfo(
            "hands-s2", "hand tracking S2: two hands with long sleeves overlap each other and the parts (10 s)",
            ("green", "blue", "purple", "cyan"), hands="s2",
        ),
        ScenarioInfo(
            "hands-s3", "hand tracking S3: bare forearm, motion blur, skin-like red/orange/yellow/wood parts (10 s)",
            ("red", "orange", "yellow", "wood"), hands="s3",
        ),
    )
}  # fmt: skip


def list_scenarios() -> list[ScenarioInfo]:
    """All scenarios in the order ``assembly-agent simulate --list`` prints them."""
    return list(SCENARIOS.values())


def get_scenario(name: str) -> ScenarioInfo:
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown simulator scenario {name!r}; choose one of: {', '.join(SCENARIOS)}") from None


# ---------------------------------------------------------------------------------------------------------
# rotations about the table's up axis


def rot_y(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` radians about the table's y (up) axis."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def wrap90(a: float) -> float:
    """Angle wrapped into [-45°, 45°) (radians)."""
    q = np.pi / 2
    return float((a + q / 2) % q - q / 2)


def wrap_pi(a: float) -> float:
    """Angle wrapped into [-180°, 180°) (radians)."""
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def cube_yaw(R: np.ndarray) -> float:
    """Yaw (mod 90°, in [-45°, 45°)) of a cube resting on one of its faces (rotation in the table frame)."""
    col = int(np.argmin(np.abs(R[1, :])))
    ax = R[:, col]
    return wrap90(float(np.arctan2(-ax[2], ax[0])))


def face_adjacent(pa: Pose, pb: Pose, edge: float = A, tol: float = 0.002, ang_tol_deg: float = 3.0) -> bool:
    """True when two cubes of ``edge`` touch face to face: centre distance within ``tol`` of ``edge``,
    orientations equal up to a cube symmetry and the offset along one of ``pa``'s face normals."""
    d = pb.t - pa.t
    dist = float(np.linalg.norm(d))
    if abs(dist - edge) > tol:
        return False
    rel = pa.R.T @ pb.R
    cos = (np.einsum("ij,nij->n", rel, cube_group()).max() - 1.0) / 2.0
    if cos < np.cos(np.radians(ang_tol_deg)):
        return False
    local = pa.R.T @ d
    return float(np.abs(local).max() / dist) > np.cos(np.radians(ang_tol_deg))


def min_jerk(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


@dataclass
class HandKey:
    """Hand key frame: time ``t`` s, hand-frame origin ``pos`` (table frame, m), ``yaw`` rad, ``grip`` 0..1."""

    t: float
    pos: np.ndarray
    yaw: float
    grip: float


@dataclass
class HandPass:
    """One visit of the hand: key frames, the carried part, grasp and release times and the part's pose
    in the hand frame while carried."""

    keys: list[HandKey]
    part: str | None = None
    t_grasp: float = 0.0
    t_release: float = 0.0
    grip_offset: Pose | None = None
    half_height: float = A / 2
    scale: float = 1.0
    side: float = 1.0
    shoulder: np.ndarray | None = None

    @property
    def t_start(self) -> float:
        return self.keys[0].t

    @property
    def t_end(self) -> float:
        return self.keys[-1].t

    def state(self, t: float) -> tuple[Pose, float]:
        """Hand pose (table frame) and grip at time ``t`` (clamped to the pass)."""
        keys = self.keys
        if t <= keys[0].t:
            k = keys[0]
            return Pose.from_rt(rot_y(k.yaw), k.pos), k.grip
        for k0, k1 in zip(keys[:-1], keys[1:], strict=True):
            if t <= k1.t:
                s = min_jerk((t - k0.t) / max(k1.t - k0.t, 1e-9))
                pos = k0.pos + s * (k1.pos - k0.pos)
                yaw = k0.yaw + s * (k1.yaw - k0.yaw)
                grip = k0.grip + s * (k1.grip - k0.grip)
                return Pose.from_rt(rot_y(yaw), pos), grip
        k = keys[-1]
        return Pose.from_rt(rot_y(k.yaw), k.pos), k.grip


@dataclass
class WanderingHand:
    """A hand of a hand-tracking scenario: its path (a part-less :class:`HandPass`), its ``albedos`` (palm,
    fingers, arm RGB; the arm is a sleeve colour with long sleeves) and whether the forearm is bare skin."""

    path: HandPass
    albedos: tuple[tuple[float, float, float], ...]
    bare_forearm: bool
    motion_blur: bool


@dataclass
class Timeline:
    """Everything that happens in a scenario, in the table frame."""

    rests: dict[str, list[tuple[float, Pose]]]
    passes: list[HandPass] = field(default_factory=list)
    events: list[ConnectionEvent] = field(default_factory=list)
    duration: float = 10.0
    hands: list[WanderingHand] = field(default_factory=list)

    def active_pass(self, t: float) -> HandPass | None:
        for p in self.passes:
            if p.t_start <= t <= p.t_end:
                return p
        return None

    def part_pose(self, name: str, t: float) -> Pose:
        """Pose of part ``name`` in the table frame at time ``t``."""
        for p in self.passes:
            if p.part == name and p.t_grasp <= t < p.t_release:
                hand, _ = p.state(t)
                return hand @ p.grip_offset
        pose = self.rests[name][0][1]
        for t0, ps in self.rests[name]:
            if t0 <= t:
                pose = ps
            else:
                break
        return pose


# ---------------------------------------------------------------------------------------------------------
# script generation


@dataclass
class ScriptSettings:
    """What the script generator needs from the simulator options (see SimOptions)."""

    speed: float = 1.0
    occlusion: float = 1.0
    excursions: bool = False
    static_duration: float = 10.0
    free_moves: int = 6
    scatter_radius: float = 0.25


class ScriptBuilder:
    """Generates the :class:`Timeline` of a scenario for a given camera (used to keep things in view)."""

    def __init__(
        self,
        info: ScenarioInfo,
        parts: list[PartSpec],
        table_to_camera: Pose,
        intr: Intrinsics,
        rng: np.random.Generator,
        settings: ScriptSettings,
    ) -> None:
        self.info = info
        self.parts = {p.name: p for p in parts}
        self.cubes = [p.name for p in parts if p.is_cube and abs(p.box[0] - A) < 1e-9]
        self.T = table_to_camera
        self._R = table_to_camera.R
        self.intr = intr
        self.rng = rng
        self.cfg = settings
        self.t = 0.0
        self.rest: dict[str, Pose] = {}
        self.rests: dict[str, list[tuple[float, Pose]]] = {}
        self.passes: list[HandPass] = []
        self.events: list[ConnectionEvent] = []
        self.connections: list[tuple[str, str]] = []

    # -- geometry helpers ----------------------------------------------------------------------------
    def project(self, p_table: np.ndarray) -> np.ndarray:
        """(u, v, z_cam) of table-frame points [N, 3]."""
        pc = np.atleast_2d(p_table) @ self._R.T + self.T.t
        z = pc[:, 2]
        u = self.intr.fx * pc[:, 0] / z + self.intr.cx
        v = self.intr.fy * pc[:, 1] / z + self.intr.cy
        return np.stack([u, v, z], axis=1)

    def in_view(self, pose: Pose, part: PartSpec, margin: float | None = None) -> bool:
        uvz = self.project(pose.transform_points(part.vertices() if part.box is not None else _hull(part)))
        w, h = self.intr.width, self.intr.height
        if margin is None:
            margin = 30.0 * w / 640.0
        return bool(
            np.all(uvz[:, 2] > 0.1)
            and np.all(uvz[:, 0] > margin)
            and np.all(uvz[:, 0] < w - margin)
            and np.all(uvz[:, 1] > margin)
            and np.all(uvz[:, 1] < h - margin)
        )

    def resting_pose(self, part: PartSpec, x: float, z: float, yaw: float, level: int = 0) -> Pose:
        """A random resting pose of ``part`` with its centre above (x, z): a random cube-group element
        (cubes), a lying box orientation (other boxes) or the mesh as given, turned by ``yaw``."""
        if part.box is not None:
            size = np.asarray(part.box)
            group = cube_group()
            if part.is_cube:
                S = group[self.rng.integers(len(group))]
            else:
                ext_y = np.abs(group) @ size
                ok = [g for g, e in zip(group, ext_y, strict=True) if abs(e[1] - size.min()) < 1e-9]
                S = ok[self.rng.integers(len(ok))]
            R = rot_y(yaw) @ S
            half_h = 0.5 * float((np.abs(R) @ size)[1])
            return Pose.from_rt(R, np.array([x, half_h + level * A, z]))
        R = rot_y(yaw)
        verts = _hull(part) @ R.T
        return Pose.from_rt(R, np.array([x, -verts[:, 1].min(), z]))

    def scatter(self, names: list[str], avoid: tuple[np.ndarray, float] | None = None) -> dict[str, Pose]:
        """Non-overlapping in-view resting poses within ``scatter_radius`` of the table centre, outside the
        disk ``avoid`` = (centre xz, radius) and away from already resting parts."""
        out: dict[str, Pose] = {}
        taken = [(p.t[[0, 2]], self.parts[n].bounding_radius()) for n, p in self.rest.items()]
        rad = self.cfg.scatter_radius
        for name in names:
            part = self.parts[name]
            rb = part.bounding_radius()
            for _ in range(4000):
                xz = self.rng.uniform(-rad, rad, size=2)
                if np.linalg.norm(xz) > rad:
                    continue
                if avoid is not None and np.linalg.norm(xz - avoid[0]) < avoid[1] + rb:
                    continue
                if any(np.linalg.norm(xz - c) < r + rb + 0.035 for c, r in taken):
                    continue
                pose = self.resting_pose(part, xz[0], xz[1], self.rng.uniform(-np.pi, np.pi))
                if not self.in_view(pose, part):
                    continue
                out[name] = pose
                taken.append((xz, rb))
                break
            else:
                raise RuntimeError(f"simulator: could not place part {name!r} on the visible table")
        return out

    def set_rest(self, name: str, pose: Pose, t: float) -> None:
        self.rest[name] = pose
        self.rests.setdefault(name, []).append((t, pose))

    # -- hand passes -------------------------------------------------------------------------------------
    def offscreen_point(self, x: float, y: float, margin: float = 110.0) -> np.ndarray:
        """A point at height ``y`` on the user's side (towards +z) that projects ``margin`` px below the image."""
        for z in np.arange(0.0, 1.6, 0.01):
            p = np.array([x, y, z])
            u, v, zc = self.project(p)[0]
            if zc < 0.15 or v > self.intr.height + margin * self.intr.height / 480.0:
                return p
        return np.array([x, y, 1.6])

    def excursion_point(self, p: np.ndarray) -> np.ndarray:
        """A point at the height of ``p`` that lies beyond the nearer left/right image border."""
        side = np.sign(p[0]) if abs(p[0]) > 0.02 else (1.0 if self.rng.random() < 0.5 else -1.0)
        for dx in np.arange(0.0, 1.5, 0.01):
            q = p + np.array([side * dx, 0.0, 0.0])
            u = self.project(q)[0, 0]
            m = 70.0 * self.intr.width / 640.0
            if u < -m or u > self.intr.width + m:
                return q
        return p + np.array([side * 1.5, 0.0, 0.0])

    def move(self, name: str, target: Pose, first_of_pair: dict[frozenset, tuple[str, str]] | None = None) -> None:
        """Append a hand pass that carries ``name`` from its rest pose to ``target`` (table frame)."""
        sp = max(self.cfg.speed, 0.05)
        occ = max(self.cfg.occlusion, 0.0)
        start = self.rest[name]
        part = self.parts[name]
        half_h = 0.5 * float((np.abs(start.R) @ np.asarray(part.box))[1])
        # yaw change of the cube and the hand's yaw (the cube is four-fold symmetric about the vertical)
        ycube = cube_yaw(start.R)
        ytarget = cube_yaw(target.R)
        delta = wrap90(ytarget - ycube)
        # the hand comes from the user's right (or, sometimes, left) side: its z axis points that way
        mid_x = 0.5 * (start.t[0] + target.t[0])
        p_right = 0.9 if mid_x > 0.04 else (0.15 if mid_x < -0.04 else 0.6)
        side = 1.0 if self.rng.random() < p_right else -1.0
        # the arm reaches from a shoulder beyond the bottom image border; the hand is turned by ~40° from the
        # forearm so that the carried part stays partly visible
        shoulder = self.offscreen_point(side * 0.20, 0.20, margin=240)
        mid = 0.5 * (start.t + target.t)
        to_sh = shoulder - mid
        want = float(np.arctan2(to_sh[0], to_sh[2])) + side * np.radians(40.0)
        cands = [ycube + k * np.pi / 2 for k in (-1, 0, 1, 2)]
        yh0 = min(cands, key=lambda y: abs(wrap_pi(y + delta / 2 - want)))
        yh1 = yh0 + delta
        # the target's rotation must be the start's turned by delta (cube symmetry makes that equivalent)
        target = Pose.from_rt(rot_y(delta) @ start.R, target.t)
        p0 = start.t.copy()
        p1 = target.t.copy()
        others = [n for n in self.rest if n != name]
        top = max([p0[1], p1[1]] + [self.rest[n].t[1] for n in others]) + 0.075
        t = self.t
        keys: list[HandKey] = []

        def key(dt: float, pos: np.ndarray, yaw: float, grip: float) -> None:
            nonlocal t
            t += dt / sp
            keys.append(HandKey(t, np.asarray(pos, float), float(yaw), float(grip)))

        entry = self.offscreen_point(0.5 * p0[0] + side * 0.12, 0.16)
        above0 = p0 + np.array([0.0, 0.06, 0.0])
        key(0.0, entry, yh0, 0.0)
        key(float(np.clip(np.linalg.norm(above0 - entry) / 0.45, 0.8, 1.6)), above0, yh0, 0.0)
        key(0.35, p0, yh0, 0.0)
        key(0.25, p0, yh0, 1.0)
        t_grasp = t
        lift0 = np.array([p0[0], top, p0[2]])
        key(0.45, lift0, yh0, 1.0)
        cur = lift0
        cur_yaw = yh0
        if self.cfg.excursions and self.rng.random() < 0.6:
            out = self.excursion_point(cur)
            key(float(np.clip(np.linalg.norm(out - cur) / 0.7, 0.35, 0.9)), out, cur_yaw, 1.0)
            key(float(self.rng.uniform(0.15, 0.45)), out, cur_yaw, 1.0)
            cur = out
        if occ >= 1.5 and others:
            via = self.rest[others[self.rng.integers(len(others))]].t.copy()
            via[1] = top + 0.02
            key(float(np.clip(np.linalg.norm(via - cur) / 0.3, 0.4, 1.5)), via, yh0 + delta / 2, 1.0)
            cur = via
            cur_yaw = yh0 + delta / 2
        lift1 = np.array([p1[0], top, p1[2]])
        key(float(np.clip(np.linalg.norm(lift1 - cur) / 0.3, 0.6, 2.0)), lift1, yh1, 1.0)
        if occ > 0:
            key(0.4 * occ, lift1, yh1, 1.0)
        key(0.5, p1, yh1, 1.0)
        key(0.1, p1, yh1, 1.0)
        t_release = t
        key(0.25, p1, yh1, 0.0)
        key(0.3, p1 + np.array([0.0, 0.06, 0.0]), yh1, 0.0)
        key(0.9, self.offscreen_point(0.5 * p1[0] + side * 0.12, 0.16), yh1, 0.0)

        hp = HandPass(keys, part=name, t_grasp=t_grasp, t_release=t_release, half_height=half_h, side=side,
                      shoulder=shoulder)  # fmt: skip
        hand_at_grasp, _ = hp.state(t_grasp)
        hp.grip_offset = hand_at_grasp.inverse() @ start
        hp.scale = 0.75 + 0.25 * occ
        self.passes.append(hp)

        # events: the cube's connections break when it is lifted, new ones form when it is released
        t_lift = t_grasp + 0.05
        for pair in [c for c in self.connections if name in c]:
            self.events.append(ConnectionEvent(round(t_lift, 6), "disconnected", pair))
            self.connections.remove(pair)
        self.set_rest(name, target, t_release)
        for other in others:
            op = self.parts[other]
            if not (op.is_cube and abs(op.box[0] - A) < 1e-9):
                continue
            if face_adjacent(self.rest[other], target):
                pair = (other, name)
                if first_of_pair and frozenset(pair) in first_of_pair:
                    pair = first_of_pair[frozenset(pair)]
                self.events.append(ConnectionEvent(round(t_release, 6), "connected", pair))
                self.connections.append(pair)
        self.t = t

    # -- scenarios -----------------------------------------------------------------------------------------
    def build(self) -> Timeline:
        info = self.info
        names = list(self.parts)
        if info.hands is not None:
            return self.build_hands(HAND_STYLES[info.hands])
        if info.structure is None:
            initial = self.scatter(names)
            for n in names:
                self.set_rest(n, initial[n], 0.0)
            if info.name == "free":
                self.t = 1.0
                for _ in range(self.cfg.free_moves):
                    self.free_move()
                    self.t += 0.3 / max(self.cfg.speed, 0.05)
                duration = self.t + 1.5
            else:
                duration = self.cfg.static_duration
            return Timeline(self.rests, self.passes, self.events, duration)

        s = info.structure
        cells = s.positions()
        cent = np.mean([c for c in cells.values()], axis=0)
        yaw = float(self.rng.uniform(-np.radians(20), np.radians(20)))
        site_c = np.array([self.rng.uniform(-0.03, 0.03), 0.0, self.rng.uniform(-0.03, 0.03)])
        Rs = rot_y(yaw)
        origin = site_c - Rs @ np.array([cent[0], 0.0, cent[2]]) + np.array([0.0, A / 2, 0.0])
        site_pose = Pose.from_rt(Rs, origin)
        radius = max(np.linalg.norm((c - cent)[[0, 2]]) for c in cells.values()) + 0.06
        initial = self.scatter(names, avoid=(site_c[[0, 2]], radius))
        for n in names:
            self.set_rest(n, initial[n], 0.0)
        order = self.build_order(s)
        first_of_pair = {frozenset(c): c for c in s.connections}
        self.t = 1.0
        for n in order:
            target = Pose.from_rt(Rs, site_pose.transform_points(cells[n][None])[0])
            self.move(n, target, first_of_pair)
            self.t += 0.3 / max(self.cfg.speed, 0.05)
        return Timeline(self.rests, self.passes, self.events, self.t + 1.5)

    def build_hands(self, style: HandStyle) -> Timeline:
        """Hand-tracking scenario: the parts rest, 1–2 hands enter from the bottom border, wander over the table
        (smooth minimum-jerk moves between random key points, over the parts now and then, the second hand
        close to and above the first one when ``style.overlap``) and leave at the end."""
        from tracker.sources.simulator.skin_tones import hand_albedos

        rng = self.rng
        names = list(self.parts)
        initial = self.scatter(names)
        for n in names:
            self.set_rest(n, initial[n], 0.0)
        sp = max(self.cfg.speed * style.speed, 0.05)
        # common key times: enter, wander, leave
        times = [0.0, 1.0 / sp]
        while times[-1] < style.duration:
            times.append(times[-1] + float(rng.uniform(0.8, 1.6)) / sp)
        times.append(times[-1] + 1.2 / sp)
        rad = self.cfg.scatter_radius * 0.85
        part_xz = [p.t[[0, 2]] for p in initial.values()]
        sides = [1.0, -1.0][: style.n_hands]
        hands: list[WanderingHand] = []
        first_pos: list[np.ndarray] = []
        skin = hand_albedos(rng)  # one person: both hands have the same skin tone
        for h, side in enumerate(sides):
            shoulder = self.offscreen_point(side * 0.22, 0.20, margin=240)
            keys: list[HandKey] = []
            for i, t in enumerate(times):
                if i == 0 or i == len(times) - 1:
                    pos = self.offscreen_point(side * 0.12 + float(rng.uniform(-0.05, 0.05)), 0.14)
                else:
                    r = rng.random()
                    if h == 1 and style.overlap and r < 0.45:  # close to and above the first hand
                        pos = first_pos[i] + np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.03, 0.06),
                                                       rng.uniform(-0.05, 0.05)])  # fmt: skip
                    elif style.overlap and r < 0.75 and part_xz:  # over a part
                        xz = part_xz[int(rng.integers(len(part_xz)))] + rng.uniform(-0.03, 0.03, size=2)
                        pos = np.array([xz[0], A + rng.uniform(0.015, 0.05), xz[1]])
                    else:
                        lo = 0.0 if side > 0 else -rad
                        hi = rad if side > 0 else 0.0
                        if style.n_hands == 1:
                            lo, hi = -rad, rad
                        pos = np.array([rng.uniform(lo, hi), A + rng.uniform(0.015, 0.09), rng.uniform(-rad, rad)])
                to_sh = shoulder - pos
                yaw = float(np.arctan2(to_sh[0], to_sh[2])) + side * float(np.radians(rng.uniform(5.0, 35.0)))
                keys.append(HandKey(float(t), np.asarray(pos, float), yaw, float(rng.uniform(0.0, 0.8))))
            if h == 0:
                first_pos = [k.pos for k in keys]
            path = HandPass(keys, part=None, side=side, shoulder=shoulder, scale=float(rng.uniform(0.9, 1.1)))
            albedos = skin
            if style.sleeves:
                albedos = (albedos[0], albedos[1], SLEEVE_COLORS[int(rng.integers(len(SLEEVE_COLORS)))])
            hands.append(WanderingHand(path, albedos, bare_forearm=not style.sleeves, motion_blur=style.motion_blur))
        return Timeline(self.rests, [], [], times[-1] + 0.2, hands)

    def build_order(self, s: Structure) -> list[str]:
        """Plan order, or a random order in which every cube is supported and touches a placed cube."""
        if self.info.order == "plan":
            return [n for n, _ in s.cells]
        cells = {n: tuple(c) for n, c in s.cells}
        placed: list[str] = []
        while len(placed) < len(cells):
            occupied = {cells[n] for n in placed}
            ok = []
            for n, (i, j, k) in cells.items():
                if n in placed:
                    continue
                if j > 0 and (i, j - 1, k) not in occupied:
                    continue
                if placed and not any(
                    (i + di, j + dj, k + dk) in occupied
                    for di, dj, dk in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))
                ):
                    continue
                ok.append(n)
            if not ok:
                raise RuntimeError(f"structure {s.name!r} cannot be built cube by cube")
            placed.append(ok[self.rng.integers(len(ok))])
        return placed

    def free_move(self) -> None:
        """One random pick-and-place: next to another cube, on top of one, or somewhere free."""
        rng = self.rng
        cubes = [n for n in self.cubes if n in self.rest]
        movable = [n for n in cubes if not any(self._on_top(o, n) for o in cubes if o != n)]
        name = movable[rng.integers(len(movable))]
        cur = self.rest[name]
        others = [n for n in cubes if n != name]
        mode = rng.choice(["adjacent", "top", "free"], p=[0.45, 0.15, 0.40])
        target = None
        if mode in ("adjacent", "top") and others:
            other = others[rng.integers(len(others))]
            op = self.rest[other]
            if mode == "adjacent" and op.t[1] > A:
                mode = "free"
            Ro = op.R
            ya = cube_yaw(Ro)
            R_new = rot_y(wrap90(ya - cube_yaw(cur.R))) @ cur.R
            if mode == "free":
                pass
            elif mode == "top":
                if op.t[1] < A and not any(self._on_top(o, other) for o in cubes if o != other):
                    target = Pose.from_rt(R_new, op.t + np.array([0.0, A, 0.0]))
            else:
                dirs = [rot_y(ya) @ d for d in ([1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0], [0, 0, -1.0])]
                for i in rng.permutation(4):
                    p = op.t + A * dirs[i]
                    p[1] = A / 2
                    cand = Pose.from_rt(R_new, p)
                    if self._free_spot(p, exclude=(name, other)) and self.in_view(cand, self.parts[name]):
                        target = cand
                        break
        if target is None:
            rad = self.cfg.scatter_radius
            for _ in range(2000):
                xz = rng.uniform(-rad, rad, size=2)
                if np.linalg.norm(xz) > rad:
                    continue
                p = np.array([xz[0], A / 2, xz[1]])
                if not self._free_spot(p, exclude=(name,), clearance=0.085):
                    continue
                d = float(rng.uniform(-np.pi / 4, np.pi / 4))
                cand = Pose.from_rt(rot_y(d) @ cur.R, p)
                if self.in_view(cand, self.parts[name]):
                    target = cand
                    break
        if target is None:
            return
        self.move(name, target)

    def _on_top(self, upper: str, lower: str) -> bool:
        d = self.rest[upper].t - self.rest[lower].t
        return abs(d[1] - A) < 0.004 and np.hypot(d[0], d[2]) < 0.01

    def _free_spot(self, p: np.ndarray, exclude: tuple[str, ...], clearance: float = 0.06) -> bool:
        for n, pose in self.rest.items():
            if n in exclude:
                continue
            if np.hypot(*(pose.t - p)[[0, 2]]) < clearance:
                return False
        return np.hypot(p[0], p[2]) < self.cfg.scatter_radius + 0.03


def _hull(part: PartSpec) -> np.ndarray:
    """Vertices of a part's convex hull (for view checks and resting)."""
    mesh = part.load_mesh()
    return np.asarray(mesh.convex_hull.vertices)
