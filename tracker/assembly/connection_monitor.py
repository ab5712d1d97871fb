"""Connection monitor: which connections exist, frame by frame (spec sections 7–10).

:class:`ConnectionMonitor` checks a list of desired connections every frame (with cube symmetry,
:mod:`tracker.assembly.cube_symmetry`), counts one as established after ``N_checks`` consecutive frames
that pass the per-axis position test (margins ``m_p``) and the rotation test (margin ``m_q``), and emits
timestamped events. It also notices face-to-face contacts that no connection of the task asked for
(:class:`AdjacencyDetector`), reported with ``expected=False``.

Breaking (not given in the thesis; chosen here): an established connection breaks after ``N_break``
consecutive frames failing a relaxed test (position margins ``break_factor · m_p``, rotation margin of
``2 · m_q_deg``). Frames in which a part of the connection has no pose leave its state unchanged.

Hand gate (hand-tracking spec §14.7; ``AssemblyParams.hand_gate``): :attr:`ConnectionMonitor.touched` holds the parts
a hand touches this frame (set by the caller from :mod:`tracker.hands.contact`; None = no hand tracking, gate open).
A connection whose test has held for ``N_checks`` frames while a hand touches one of its parts becomes *pending*
(``ConnectionStatus.pending``, state stays "near"); it is established at the first frame at which neither part has
been touched for ``n_release`` consecutive frames with the test still holding; if the test fails meanwhile, the
candidate is dropped and the count restarts.
Times are the ``t`` values passed to :meth:`ConnectionMonitor.update` (seconds).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from tracker.assembly.connection_score import allocate_particles, connection_score
from tracker.assembly.cube_symmetry import Option, SymmetryState
from tracker.assembly.relations import (
    margins,
    norm3,
    normalised_position_error,
    relative_pose,
    relative_position_table,
    rotation_dot,
    table_rotation,
)
from tracker.filter.connection_hint import ConnectionHint
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


@dataclass
class AssemblyParams:
    """Parameters of the connection tests (defaults: the thesis's Experiments 2/3 setting, m_q chosen).

    * ``m_p``: per-axis position margin(s), metres (5.11); ``m_q_deg``: rotation tolerance in degrees,
      ``m_q = 1 − cos(m_q_deg / 2)`` (5.13); ``yaw_tolerance_deg``: cubes are compared levelled and with
      the first cube's heading turned by up to this angle towards the observed offset (0 = off; see
      :func:`~tracker.assembly.cube_symmetry.levelled_frames`); ``free_yaw_tolerance_deg``: the same turn
      for a first cube without a stored prior (its heading comes only from the tracker, which often ends ~45°
      off after a cube was carried; the larger of the two applies; 180 (default) = the heading follows the
      observed offset whatever the tracked heading, which after levelling may leave more than 45° with the
      face chosen from the tracked rotation; the same bound forgives the yaw residual of a second cube
      without a prior); ``K``: score sensitivity (5.16); ``N_max``:
      maximum particles per connection (5.19); ``N_checks``: consecutive passing frames to establish a connection;
      ``N_break`` / ``break_factor``: hysteresis for breaking; ``near_score``: score above which an open
      connection is reported as "near"; ``hand_gate``: hold connections back while a hand touches one of their
      parts (hand-tracking spec §14.7; only when the caller reports touched parts); ``n_release``: frames without
      touch that confirm a pending connection.
    """

    m_p: float = 0.01
    m_q_deg: float = 45.0
    yaw_tolerance_deg: float = 40.0
    free_yaw_tolerance_deg: float = 180.0
    K: float = 3.0
    N_max: int = 9
    N_checks: int = 2
    N_break: int = 6
    break_factor: float = 1.5
    near_score: float = 0.5
    hand_gate: bool = True
    n_release: int = 3

    @classmethod
    def from_dict(cls, d: dict | None, **overrides) -> AssemblyParams:
        names = {f.name for f in fields(cls)}
        merged = {**{k: v for k, v in (d or {}).items() if k in names}, **overrides}
        p = cls(**merged)
        p.N_max, p.N_checks, p.N_break, p.n_release = int(p.N_max), int(p.N_checks), int(p.N_break), int(p.n_release)
        p.hand_gate = bool(p.hand_gate)
        if p.N_checks < 1 or p.N_break < 1 or p.n_release < 1:
            raise ValueError("N_checks, N_break and n_release must be at least 1")
        margins(p.m_p)
        return p

    @property
    def m_q(self) -> float:
        return float(1.0 - np.cos(np.radians(self.m_q_deg) / 2.0))

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ConnectionSpec:
    """A desired connection: pose (``p_des`` metres, ``R_des``) of ``second`` in ``first``'s frame."""

    first: str
    second: str
    p_des: np.ndarray
    R_des: np.ndarray

    @property
    def key(self) -> frozenset:
        return frozenset((self.first, self.second))

    @staticmethod
    def from_pose(first: str, second: str, pose: Pose) -> ConnectionSpec:
        return ConnectionSpec(first, second, np.asarray(pose.t, float), pose.R)


@dataclass
class MonitorEvent:
    """A connection was established (``"connected"``) or broken (``"disconnected"``) at ``t`` seconds."""

    t: float
    type: str
    first: str
    second: str
    expected: bool = True

    def to_dict(self) -> dict:
        return {"t": round(self.t, 4), "type": self.type, "parts": [self.first, self.second], "expected": self.expected}


@dataclass
class ConnectionStatus:
    """Current state of one connection: ``state`` is ``open``, ``near`` or ``connected``; ``pending``: its test
    holds but a hand touches one of its parts (or let go fewer than ``n_release`` frames ago)."""

    first: str
    second: str
    state: str = "open"
    score: float = 0.0
    since: float | None = None
    expected: bool = True
    passing: bool = False
    count: int = 0
    fail_count: int = 0
    established_at: float | None = None
    pending: bool = False
    free_count: int = 0
    option: Option | None = field(default=None, repr=False)
    offset_table: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {
            "first": self.first,
            "second": self.second,
            "state": self.state,
            "score": round(float(self.score), 4),
            "since": None if self.since is None else round(float(self.since), 4),
            "expected": self.expected,
            "pending": self.pending,
        }


def _set_state(st: ConnectionStatus, state: str, t: float) -> None:
    if st.state != state:
        st.state = state
        st.since = t


class ConnectionMonitor:
    """Monitors the desired connections of one structure (one binary state vector v_c)."""

    def __init__(
        self,
        parts: Iterable[PartSpec],
        connections: list[ConnectionSpec],
        params: AssemblyParams | None = None,
        detect_unexpected: bool = True,
    ):
        self.parts = {p.name: p for p in parts}
        self.connections = list(connections)
        for c in self.connections:
            for n in (c.first, c.second):
                if n not in self.parts:
                    raise ValueError(f"connection {c.first}–{c.second}: unknown part {n!r}")
        self.params = params or AssemblyParams()
        self.touched: set[str] | None = None
        """Parts a hand touches in the current frame (None: no hand tracking; see the hand gate above)."""
        self.symmetry = SymmetryState({n: p.is_cube for n, p in self.parts.items()})
        self.adjacency = (
            AdjacencyDetector(self.parts.values(), self.params, exclude={c.key for c in self.connections})
            if detect_unexpected
            else None
        )
        self.reset()

    def reset(self) -> None:
        self.status = [ConnectionStatus(c.first, c.second) for c in self.connections]
        self.events: list[MonitorEvent] = []
        self.symmetry.reset()
        if self.adjacency is not None:
            self.adjacency.reset()

    # ------------------------------------------------------------------ per frame
    def _error(self, spec: ConnectionSpec, p: np.ndarray, R: np.ndarray) -> float:
        ang = 2.0 * np.arccos(min(max(rotation_dot(spec.R_des, R), 0.0), 1.0))
        return normalised_position_error(spec.p_des, p, self.params.m_p) + (ang / np.radians(self.params.m_q_deg)) ** 2

    def _passes(self, spec: ConnectionSpec, o: Option, factor: float = 1.0, dy: float | None = None) -> bool:
        """Per-axis position test (5.11) and rotation test (5.13) on the symmetry-corrected relative pose.

        ``dy``: the measured height of the second part above the first (table normal, eq. 5.8). When the
        first part is a cube its fundamental orientation has y up, so the height must match ``p_des[1]``
        within ``m_p,y``: the vertical axis is checked in the table frame, independent of the (noisier)
        estimated orientations.
        """
        m = factor * margins(self.params.m_p)
        pos_ok = bool(np.all(np.abs(spec.p_des - o.p) < m))
        if dy is not None and abs(dy - spec.p_des[1]) >= m[1]:
            return False
        m_q = 1.0 - np.cos(np.radians(self.params.m_q_deg * factor) / 2.0)
        return pos_ok and rotation_dot(spec.R_des, o.R) >= 1.0 - m_q

    def _far_apart(self, spec: ConnectionSpec, pa: Pose, pb: Pose) -> bool:
        """True when the parts are so far from the desired distance that the score is below 0.5 / N_max
        whatever the symmetry choice (|‖d‖ − ‖p_des‖| bounds every per-axis error from below)."""
        prm = self.params
        dist = norm3(pb.t - pa.t)
        gap = abs(dist - norm3(spec.p_des)) / float(margins(prm.m_p).max())
        e_min = ((2.0 * max(prm.N_max, 1)) ** 2 - 1.0) / max(prm.K, 1e-9) + 3.0
        return gap * gap > max(e_min, 3.0 * prm.break_factor**2 * 3.0)

    def update(
        self, t: float, poses: dict[str, Pose], table_to_camera: Pose, active: Iterable[int] | None = None
    ) -> list[ConnectionStatus]:
        """Check the connections (all, or the indices in ``active`` plus the established ones) at time ``t``."""
        prm = self.params
        normal = table_to_camera.R[:, 1]
        act = None if active is None else set(active)
        broke = False
        for k, (spec, st) in enumerate(zip(self.connections, self.status, strict=True)):
            established = st.state == "connected"
            if act is not None and k not in act and not established:
                st.count = 0
                continue
            pa, pb = poses.get(spec.first), poses.get(spec.second)
            if pa is None or pb is None:
                continue
            if self._far_apart(spec, pa, pb):
                # cannot pass and would get no particles (score < 0.5 / N_max): skip the symmetry search
                st.passing, st.score, st.count = False, 0.0, 0
                st.offset_table = relative_position_table(pa.t, pb.t, table_rotation(table_to_camera))
                if established:
                    st.fail_count += 1
                    if st.fail_count >= prm.N_break:
                        st.established_at = None
                        _set_state(st, "open", t)
                        self.events.append(MonitorEvent(t, "disconnected", spec.first, spec.second, True))
                        broke = True
                else:
                    _set_state(st, "open", t)
                continue
            p_ab, R_ab = relative_pose(pa, pb)
            res = self.symmetry.resolve(
                spec.first, spec.second, p_ab, R_ab, pa.R, spec.p_des, spec.R_des, normal,
                lambda p, R, s=spec: self._error(s, p, R),
                yaw_tolerance=np.radians(prm.yaw_tolerance_deg) if prm.yaw_tolerance_deg > 0 else None,
                free_yaw_tolerance=np.radians(prm.free_yaw_tolerance_deg) if prm.yaw_tolerance_deg > 0 else None,
            )
            best = res.best
            st.option = best
            st.offset_table = relative_position_table(pa.t, pb.t, table_rotation(table_to_camera))
            dy = float(st.offset_table[1]) if self.parts[spec.first].is_cube else None
            st.passing = self._passes(spec, best, dy=dy)
            st.score = connection_score(spec.p_des, spec.R_des, best.p, best.R, prm.m_p, prm.K)
            if not established:
                st.count = st.count + 1 if st.passing else 0
                if st.count >= prm.N_checks and self._held_back(spec, st):
                    _set_state(st, "near", t)
                elif st.count >= prm.N_checks:
                    self.symmetry.establish(spec.first, spec.second, res,
                                            lambda o, s=spec, h=dy: self._passes(s, o, dy=h))
                    st.established_at = t
                    st.fail_count = 0
                    _set_state(st, "connected", t)
                    self.events.append(MonitorEvent(t, "connected", spec.first, spec.second, True))
                else:
                    st.pending, st.free_count = False, 0
                    _set_state(st, "near" if (st.passing or st.score >= prm.near_score) else "open", t)
            else:
                ok = self._passes(spec, best, prm.break_factor, dy=dy)
                st.fail_count = 0 if ok else st.fail_count + 1
                if st.fail_count >= prm.N_break:
                    st.count = 0
                    st.established_at = None
                    _set_state(st, "open", t)
                    self.events.append(MonitorEvent(t, "disconnected", spec.first, spec.second, True))
                    broke = True
        if broke:
            self.symmetry.rebuild([(c.first, c.second) for c, s in zip(self.connections, self.status, strict=True)
                                   if s.state == "connected"])
        if self.adjacency is not None:
            self.events.extend(self.adjacency.update(t, poses, table_to_camera))
        return self.status

    def _held_back(self, spec: ConnectionSpec, st: ConnectionStatus) -> bool:
        """The hand gate for a connection whose test has held ``N_checks`` frames: True while it must stay pending
        (a hand touches one of its parts, or let go fewer than ``n_release`` frames ago); updates ``st.pending``."""
        if not self.params.hand_gate or self.touched is None:
            st.pending, st.free_count = False, 0
            return False
        if spec.first in self.touched or spec.second in self.touched:
            st.pending, st.free_count = True, 0
            return True
        if not st.pending:
            return False
        st.free_count += 1
        if st.free_count >= self.params.n_release:
            st.pending, st.free_count = False, 0
            return False
        return True

    # ------------------------------------------------------------------ outputs
    @property
    def established(self) -> list[bool]:
        """The binary state vector v_c."""
        return [s.state == "connected" for s in self.status]

    def n_established(self) -> int:
        return sum(self.established)

    def unexpected(self) -> list[ConnectionStatus]:
        """Face-to-face contacts between parts that no desired connection covers (established ones)."""
        return [] if self.adjacency is None else self.adjacency.connected()

    def connection_hints(self) -> list[ConnectionHint]:
        """Hints for the tracker: locked (N_max) when established, else ``round(score · N_max)`` particles.

        The relative pose is mapped into the tracker's own part frames: ``p = Q_aᵀ p_des``,
        ``R = Q_aᵀ R_des Q_b`` with the current symmetry choice.
        """
        out = []
        for spec, st in zip(self.connections, self.status, strict=True):
            if st.option is None:
                continue
            locked = st.state == "connected"
            n = self.params.N_max if locked else allocate_particles(st.score, self.params.N_max)
            if n <= 0:
                continue
            Q_a, Q_b = st.option.Q_a, st.option.Q_b
            rel = Pose.from_rt(Q_a.T @ spec.R_des @ Q_b, Q_a.T @ spec.p_des)
            out.append(ConnectionHint(spec.first, spec.second, rel, int(n), locked))
        return out

    def to_list(self) -> list[dict]:
        out = [s.to_dict() for s in self.status]
        out += [s.to_dict() for s in self.unexpected()]
        return out


class AdjacencyDetector:
    """Face-to-face contacts between box parts, whatever their orientation (cube symmetry is implicit).

    Two boxes touch when b's centre, in a's frame, lies at ``±(e_a + e_b)/2`` along one axis of a (e = the
    extents along that axis) within the per-axis margins ``m_p``. Counted like connections (N_checks to
    establish, N_break with ``break_factor`` to break). ``offset_table`` of each status is b − a in the table
    frame (x to the user's right, y up), used to read rows left to right.
    """

    def __init__(self, parts: Iterable[PartSpec], params: AssemblyParams, exclude: set[frozenset] | None = None):
        self.parts = {p.name: p for p in parts if p.box is not None}
        self.params = params
        self.exclude = exclude or set()
        names = list(self.parts)
        all_pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1 :]]
        self.pairs = [pr for pr in all_pairs if frozenset(pr) not in self.exclude]
        self._equal_sizes: dict[tuple, bool] = {}  # (extents of a, extents of b) -> equal cubes (touching)
        self.reset()

    def reset(self) -> None:
        self.status = {pair: ConnectionStatus(pair[0], pair[1], expected=False) for pair in self.pairs}

    def _equal_cubes(self, size_a, size_b) -> bool:
        """Both boxes the same cube (extents equal within ``np.allclose``), remembered per pair of sizes."""
        key = (tuple(np.ravel(size_a).tolist()), tuple(np.ravel(size_b).tolist()))
        same = self._equal_sizes.get(key)
        if same is None:
            same = self._equal_sizes[key] = bool(np.ptp(size_a) < 1e-9 and np.allclose(size_a, size_b))
        return same

    def touching(self, pa: Pose, pb: Pose, size_a, size_b, factor: float = 1.0, R_ot: np.ndarray | None = None
                 ) -> bool:
        """Face contact of two boxes. Two equal cubes are tested in the table frame without orientations
        (side by side: height < m and horizontal distance = edge ± m; stacked: horizontal distance < m and
        height = edge ± m, with m = min(m_p, edge / 4)); other boxes in a's body frame."""
        m = factor * margins(self.params.m_p)
        if R_ot is not None and self._equal_cubes(size_a, size_b):
            d = R_ot @ (pb.t - pa.t)
            h = float(np.hypot(d[0], d[2]))
            a = float(size_a[0])
            m = np.minimum(m, 0.25 * a)  # a diagonal neighbour is (√2 − 1)·a ≈ 0.41 a away from contact
            side = abs(d[1]) < m[1] and abs(h - a) < min(m[0], m[2])
            stacked = h < min(m[0], m[2]) and abs(abs(d[1]) - a) < m[1]
            return bool(side or stacked)
        p_ab, R_ab = relative_pose(pa, pb)
        i = int(np.argmax(np.abs(p_ab)))
        ext_b = np.abs(R_ab) @ np.asarray(size_b, float)
        target = np.zeros(3)
        target[i] = np.sign(p_ab[i]) * (size_a[i] + ext_b[i]) / 2.0
        return bool(np.all(np.abs(p_ab - target) < m))

    def update(self, t: float, poses: dict[str, Pose], table_to_camera: Pose) -> list[MonitorEvent]:
        prm = self.params
        R_ot = table_rotation(table_to_camera)
        events = []
        for (a, b), st in self.status.items():
            pa, pb = poses.get(a), poses.get(b)
            if pa is None or pb is None:
                continue
            sa, sb = self.parts[a].box, self.parts[b].box
            st.offset_table = relative_position_table(pa.t, pb.t, R_ot)
            if st.state != "connected":
                st.passing = self.touching(pa, pb, sa, sb, R_ot=R_ot)
                st.count = st.count + 1 if st.passing else 0
                st.score = 1.0 if st.passing else 0.0
                if st.count >= prm.N_checks:
                    _set_state(st, "connected", t)
                    st.established_at = t
                    st.fail_count = 0
                    events.append(MonitorEvent(t, "connected", a, b, False))
            else:
                ok = self.touching(pa, pb, sa, sb, prm.break_factor, R_ot=R_ot)
                st.fail_count = 0 if ok else st.fail_count + 1
                if st.fail_count >= prm.N_break:
                    st.count = 0
                    st.score = 0.0
                    _set_state(st, "open", t)
                    events.append(MonitorEvent(t, "disconnected", a, b, False))
        return events

    def connected(self) -> list[ConnectionStatus]:
        return [s for s in self.status.values() if s.state == "connected"]


def specs_from_structure(task, structure) -> list[ConnectionSpec]:
    """Connection specs (metres) of a :class:`~tracker.assembly.task_file.StructureModel` of ``task``."""
    return [ConnectionSpec.from_pose(c.first, c.second, task.connection_pose(c)) for c in structure.connections]
