"""Cube symmetry with stored prior rotations (spec sections 8.3–8.4, the four cases).

A cube's observed orientation ``R`` is only known up to the 24 cube rotations ``G``. For each connection
(first part ``a``, second part ``b``) we choose ``Q_a, Q_b ∈ G`` so that the corrected orientations
``R_a Q_aᵀ`` and ``R_b Q_bᵀ`` are the parts' fundamental orientations; the corrected relative pose is
``p' = Q_a p_ab``, ``R' = Q_a R_ab Q_bᵀ`` and is compared with the desired one (section 7).

Cases (a part "has a prior" when it belongs to an established connection):

1. neither part has a prior: ``Q_a`` maximises ``(S p_ab)·p_des``; ``Q_b`` = nearest element of G to
   ``R_desᵀ Q_a R_ab``;
2. only ``a`` has a prior: ``Q_a`` stored, ``Q_b`` as in case 1;
3. only ``b`` has a prior: ``Q_b`` stored, ``Q_a`` = nearest element to ``R_des Q_b R_abᵀ``;
4. both have priors: both stored.

Choices documented here (the thesis leaves them open):

* Case 1 first keeps the rotations that make the first cube's corrected y axis point up along the table
  normal (best ``N·(R_a Sᵀ ŷ)``, ties within 1e-3), and only then maximises the dot product (ties within
  1e-6 relative). This keeps the vertical axis fixed and the horizontal axes free (Fig. 5.5, eq. 5.8), so a
  cube beside another never satisfies an "on top of" connection. (Spec 8.4 orders the two criteria the
  other way round; with that order a vertical connection would accept any face neighbour.)
* A prior is stored as the part's fundamental orientation in the camera frame, ``F`` (``Q`` = nearest
  element of G to ``Fᵀ R`` each frame, for the tracker hints). Without ``yaw_tolerance`` F is re-anchored
  every frame, ``F ← R Qᵀ``. With ``yaw_tolerance`` (the monitor's default) the priors are *structural*: the
  first and second parts' F are levelled, the first is turned towards the observed offset (within the
  tolerance), the second part gets ``F_b = F_a R_des`` when it is new to the component, and a component's
  headings are turned with the observed offsets of its connections; the tracker's orientation estimates
  are then used only to pick the discrete symmetry for a part that has no prior yet.
* (Re-anchoring, without ``yaw_tolerance``:) The tracker does not
  know about symmetry, so its estimate of a cube may turn into another equivalent orientation (a 90° jump
  or a slow drift about the vertical); a fixed ``Q`` would then point the fundamental frame elsewhere,
  whereas ``F`` stays with the physical structure (changes below 45° per frame are absorbed).
* Priors are stored when a connection becomes established, as *hypotheses per connected component*: a
  vertical first connection leaves the structure's heading undetermined (four rotations about the normal
  tie), so all tied choices are kept and later horizontal connections pick the one that fits. A component's
  hypotheses are narrowed to those that pass the test when a new connection joins it, and projected onto
  the remaining parts when a connection breaks.
* Parts that are not cubes have no symmetry: their ``Q`` is always the identity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.assembly.relations import cross3, norm3
from tracker.geometry.symmetry import cube_group, nearest_in_group

UP_TIE_TOL = 1e-3
DOT_TIE_TOL = 1e-6
MAX_HYPOTHESES = 24
UPDATE_ERROR = 3.0
"""Structural priors turn with the observed offsets only when the check's error (normalised) is at most this."""

_I = np.eye(3)


def case1_first_rotations(p_ab: np.ndarray, p_des: np.ndarray, R_a: np.ndarray, normal: np.ndarray) -> list[int]:
    """Indices into :func:`cube_group` of the case-1 choices for ``Q_a`` (all tied options, best first)."""
    G = cube_group()
    n = np.asarray(normal, float)
    # Corrected y axis of the first cube in the camera frame: R_a Sᵀ ŷ = R_a · (row 1 of S).
    up = np.einsum("ij,nj->ni", R_a, G[:, 1, :]) @ n if R_a is not None else None
    cand = np.arange(len(G))
    if up is not None:
        cand = cand[up >= up.max() - UP_TIE_TOL]
    dots = np.einsum("nij,j->ni", G[cand], p_ab) @ np.asarray(p_des, float)
    tol = DOT_TIE_TOL * (norm3(p_ab) * norm3(p_des) + 1e-12)
    best = cand[dots >= dots.max() - tol]
    return [int(i) for i in best]


def _rotation_onto(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``u`` onto unit vector ``v``."""
    axis = cross3(u, v)
    s, c = norm3(axis), min(max(float(u @ v), -1.0), 1.0)  # = np.clip, NaN too
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        w = cross3(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        w /= norm3(w)
        return 2.0 * np.outer(w, w) - np.eye(3)  # 180° about an axis perpendicular to u
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def levelled_frames(F_a: np.ndarray, F_b: np.ndarray | None, normal: np.ndarray, p_des: np.ndarray,
                    d: np.ndarray, yaw_tolerance: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Fundamental orientations made robust to the tracker's orientation noise (choice documented here).

    Returns ``(L_a, L_b, Rz)``: both orientations levelled (smallest rotation taking their y axis onto the
    table normal ``normal``) and ``Rz``, a turn about the normal. When the desired offset ``p_des`` is mostly
    horizontal, ``Rz`` turns the desired direction ``L_a p_des`` onto the observed offset ``d`` (camera
    frame) if the angle is within ``yaw_tolerance`` (identity otherwise); ``L_a`` includes the turn,
    ``L_b`` does not. The tolerance stays below 45° so that the four horizontal directions (90° apart)
    remain distinct.
    """
    n = np.asarray(normal, float) / norm3(normal)
    La = _rotation_onto(F_a[:, 1], n) @ F_a
    Lb = None if F_b is None else _rotation_onto(F_b[:, 1], n) @ F_b
    u = La @ p_des
    u_h = u - (u @ n) * n
    v_h = d - (d @ n) * n
    Rz = np.eye(3)
    if norm3(u_h) > 0.5 * norm3(p_des) and norm3(v_h) > 1e-6:
        phi = float(np.arctan2(n @ cross3(u_h, v_h), u_h @ v_h))
        if abs(phi) <= yaw_tolerance:
            K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
            Rz = np.eye(3) + np.sin(phi) * K + (1 - np.cos(phi)) * K @ K
    return Rz @ La, Lb, Rz


def snap_to_group(M: np.ndarray) -> np.ndarray:
    """Nearest cube rotation to ``M`` (argmax over G of |q_S · q_M|, i.e. smallest angle)."""
    return nearest_in_group(M)[1]


@dataclass
class Option:
    """One symmetry choice for a connection check: rotations, corrected relative pose and its error."""

    Q_a: np.ndarray
    Q_b: np.ndarray
    p: np.ndarray
    R: np.ndarray
    error: float
    hyp_a: int | None = None
    hyp_b: int | None = None
    F_a: np.ndarray | None = None
    F_b: np.ndarray | None = None
    turn: np.ndarray | None = None
    realign: np.ndarray | None = None


@dataclass
class Resolution:
    """Result of :meth:`SymmetryState.resolve`: the case (1–4) and the options, best first."""

    case: int
    options: list[Option] = field(default_factory=list)

    @property
    def best(self) -> Option:
        return self.options[0]


class SymmetryState:
    """Stored prior rotations of symmetric parts, as hypotheses per connected component."""

    def __init__(self, symmetric: dict[str, bool]):
        self.symmetric = dict(symmetric)
        self.reset()

    def reset(self) -> None:
        self._component: dict[str, int] = {}
        self._hyps: dict[int, list[dict[str, np.ndarray]]] = {}  # part → F (fundamental orientation)
        self._next_id = 0

    # ------------------------------------------------------------------ queries
    def has_prior(self, part: str) -> bool:
        return part in self._component

    def hypotheses(self, part: str) -> list[dict[str, np.ndarray]]:
        cid = self._component.get(part)
        return self._hyps[cid] if cid is not None else []

    def fundamental(self, part: str) -> np.ndarray | None:
        """The stored fundamental orientation ``F = R Qᵀ`` (camera frame) of a part (first hypothesis) or None."""
        h = self.hypotheses(part)
        return h[0][part] if h else None

    def prior_rotation(self, part: str, R: np.ndarray) -> np.ndarray | None:
        """The prior ``P = Qᵀ`` for the observed orientation ``R`` (first hypothesis), or ``None``."""
        F = self.fundamental(part)
        return None if F is None else snap_to_group(F.T @ R).T

    def _reanchor(self, part: str, R: np.ndarray, symmetric: bool, update: bool) -> list[tuple[np.ndarray, np.ndarray]]:
        """``(Q, F)`` of every hypothesis of ``part`` for orientation ``R``: ``Q`` = nearest element of G to
        ``Fᵀ R``. With ``update`` the stored F follows the tracker (``F ← R Qᵀ``)."""
        out = []
        for h in self.hypotheses(part):
            Q = snap_to_group(h[part].T @ R) if symmetric else _I
            if update:
                h[part] = R @ Q.T
            out.append((Q, h[part]))
        return out

    # ------------------------------------------------------------------ checking
    def resolve(
        self,
        a: str,
        b: str,
        p_ab: np.ndarray,
        R_ab: np.ndarray,
        R_a: np.ndarray,
        p_des: np.ndarray,
        R_des: np.ndarray,
        normal: np.ndarray,
        error_fn,
        yaw_tolerance: float | None = None,
        free_yaw_tolerance: float | None = None,
    ) -> Resolution:
        """All symmetry options for checking connection (a, b), best (smallest ``error_fn(p, R)``) first.

        With ``yaw_tolerance`` (radians), cube orientations are first levelled (their fundamental y axis
        turned onto the table normal: cubes in a structure rest level) and the first cube's heading is then
        turned about the normal by up to ``yaw_tolerance`` towards the observed offset (see
        :func:`levelled_frames`); the comparison then depends on positions and the discrete symmetry choice,
        not on the tracker's small orientation errors. ``free_yaw_tolerance`` (radians, used instead when larger)
        applies when the first cube has no stored prior, i.e. its heading comes only from the tracker's
        orientation estimate: a cube that the hand carried and released is often tracked with a heading error
        near 45°, between two faces, so a 40° tolerance would reject a true connection for seconds. The
        discrete face choice (case 1) already leaves every horizontal direction open for such a cube, so
        turning by up to 45° changes only the residual angle, not which faces can connect. Likewise the yaw
        residual of a second cube without a prior (levelled, modulo 90°) is forgiven up to the same angle.
        """
        sym_a, sym_b = self.symmetric.get(a, False), self.symmetric.get(b, False)
        G = cube_group()
        R_b = R_a @ R_ab
        structural = yaw_tolerance is not None
        ha_full = self._reanchor(a, R_a, sym_a, update=not structural)
        hb_full = self._reanchor(b, R_b, sym_b, update=not structural)
        ha = [q for q, _ in ha_full]
        hb = [q for q, _ in hb_full]
        same_component = bool(ha) and bool(hb) and self._component[a] == self._component[b]

        def q_b_free(Q_a):
            return snap_to_group(R_des.T @ Q_a @ R_ab) if sym_b else _I

        def q_a_free(Q_b):
            return snap_to_group(R_des @ Q_b @ R_ab.T) if sym_a else _I

        pairs: list[tuple[np.ndarray, np.ndarray, int | None, int | None]] = []
        if ha and hb:
            case = 4
            if same_component:
                pairs = [(x, y, i, i) for i, (x, y) in enumerate(zip(ha, hb, strict=True))]
            else:
                pairs = [(x, y, i, j) for i, x in enumerate(ha) for j, y in enumerate(hb)]
        elif ha:
            case = 2
            pairs = [(x, q_b_free(x), i, None) for i, x in enumerate(ha)]
        elif hb:
            case = 3
            pairs = [(q_a_free(y), y, None, j) for j, y in enumerate(hb)]
        else:
            case = 1
            if sym_a:
                firsts = [G[i] for i in case1_first_rotations(p_ab, p_des, R_a, normal)]
            else:
                firsts = [_I]
            pairs = [(Q_a, q_b_free(Q_a), None, None) for Q_a in firsts]
        options = []
        d = R_a @ p_ab  # p_b − p_a in the camera frame
        for Q_a, Q_b, i, j in pairs:
            F_a, F_b = R_a @ Q_a.T, R_b @ Q_b.T
            turn = None
            if structural and sym_a:
                # structural priors: stored F (not the tracker's orientation) for parts that have one
                base_a = ha_full[i][1] if i is not None else F_a
                base_b = hb_full[j][1] if j is not None else F_b
                tol = yaw_tolerance
                if i is None and free_yaw_tolerance is not None:
                    tol = max(tol, free_yaw_tolerance)
                La, Lb, turn = levelled_frames(base_a, base_b if sym_b else None, normal, p_des, d, tol)
                if same_component and Lb is not None:
                    Lb = turn @ Lb
                p = La.T @ d
                Lb_test = Lb
                if sym_b and j is None and Lb is not None and free_yaw_tolerance is not None:
                    # a second cube without a prior: its tracked heading is as unreliable as the first's; levelled,
                    # its heading is only defined modulo 90° (cube symmetry), so the yaw residual to the desired
                    # heading is taken modulo 90° (|φ| ≤ 45°) and forgiven up to free_yaw_tolerance
                    M = _heading_turn(Lb, La @ R_des, normal, modulo=np.pi / 2)
                    if M is not None and np.arccos(np.clip((np.trace(M) - 1.0) / 2.0, -1.0, 1.0)) <= free_yaw_tolerance:
                        Lb_test = La @ R_des
                R = La.T @ (Lb_test if sym_b else R_b)
                F_a = La
                F_b = Lb if (j is not None and Lb is not None) else (La @ R_des if sym_b else R_b)
            else:
                p = Q_a @ p_ab
                R = Q_a @ R_ab @ Q_b.T
            o = Option(Q_a, Q_b, p, R, float(error_fn(p, R)), i, j, F_a, F_b)
            o.turn = turn
            if structural and sym_a and sym_b and i is None and j is not None:
                # case 3: a new cube joins b's component; its heading (turned onto the observed offset) re-anchors
                # the component's heading (see establish)
                o.realign = _heading_turn(F_b, La @ R_des, normal)
            options.append(o)
        options.sort(key=lambda o: o.error)
        best = options[0]
        if structural and best.turn is not None and best.hyp_a is not None and best.error <= UPDATE_ERROR:
            # the component's heading follows the observed positions of its parts
            for part, F in self._hyps[self._component[a]][best.hyp_a].items():
                self._hyps[self._component[a]][best.hyp_a][part] = best.turn @ F
        return Resolution(case, options)

    # ------------------------------------------------------------------ updates
    def establish(self, a: str, b: str, resolution: Resolution, passing) -> None:
        """Store priors for the established connection (a, b): keep the options for which ``passing(option)``."""
        keep = [o for o in resolution.options if passing(o)] or resolution.options[:1]
        ca, cb = self._component.get(a), self._component.get(b)
        ha = self._hyps.get(ca, [{}]) if ca is not None else [{}]
        hb = self._hyps.get(cb, [{}]) if cb is not None else [{}]
        new: list[dict[str, np.ndarray]] = []
        for o in keep:
            if ca is not None and ca == cb:
                base = dict(ha[o.hyp_a])
            else:
                base = dict(ha[o.hyp_a] if o.hyp_a is not None else {})
                hyp_b = hb[o.hyp_b] if o.hyp_b is not None else {}
                if o.realign is not None:
                    # case 3: b's component (whose heading may only come from the tracker, e.g. after a vertical
                    # first connection) takes the heading of the new connection's observed offset
                    hyp_b = {p: o.realign @ F for p, F in hyp_b.items()}
                base.update(hyp_b)
            base[a] = o.F_a
            base[b] = o.F_b if o.realign is None else o.realign @ o.F_b
            if not any(_same_hyp(base, h) for h in new):
                new.append(base)
        new = new[:MAX_HYPOTHESES]
        cid = self._next_id
        self._next_id += 1
        members = {a, b}
        for old in (ca, cb):
            if old is not None:
                members |= {p for p, c in self._component.items() if c == old}
                self._hyps.pop(old, None)
        for p in members:
            self._component[p] = cid
        self._hyps[cid] = new

    def rebuild(self, established: list[tuple[str, str]]) -> None:
        """Recompute components after connections broke; ``established`` = the pairs still connected."""
        adj: dict[str, set[str]] = {}
        for a, b in established:
            adj.setdefault(a, set()).add(b)
            adj.setdefault(b, set()).add(a)
        old_component, old_hyps = self._component, self._hyps
        self.reset()
        seen: set[str] = set()
        for start in adj:
            if start in seen:
                continue
            comp, stack = set(), [start]
            while stack:
                p = stack.pop()
                if p in comp:
                    continue
                comp.add(p)
                stack.extend(adj[p] - comp)
            seen |= comp
            src = {old_component[p] for p in comp if p in old_component}
            hyps: list[dict[str, np.ndarray]] = []
            for c in src:
                for h in old_hyps.get(c, []):
                    proj = {p: h[p] for p in comp if p in h}
                    if proj and not any(_same_hyp(proj, x) for x in hyps):
                        hyps.append(proj)
            cid = self._next_id
            self._next_id += 1
            for p in comp:
                self._component[p] = cid
            self._hyps[cid] = hyps


def _heading_turn(F_from: np.ndarray, F_to: np.ndarray, normal: np.ndarray, modulo: float | None = None
                  ) -> np.ndarray | None:
    """Rotation about ``normal`` taking the heading of ``F_from`` onto that of ``F_to`` (both levelled: their
    y axes along the normal), the angle reduced into ``[−modulo/2, modulo/2]`` when given; None when either is
    not level."""
    n = np.asarray(normal, float) / norm3(normal)
    if F_from[:, 1] @ n < 0.99 or F_to[:, 1] @ n < 0.99:
        return None
    u, v = F_from[:, 0] - (F_from[:, 0] @ n) * n, F_to[:, 0] - (F_to[:, 0] @ n) * n
    phi = float(np.arctan2(n @ cross3(u, v), u @ v))
    if modulo is not None:
        phi = (phi + modulo / 2.0) % modulo - modulo / 2.0
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + np.sin(phi) * K + (1 - np.cos(phi)) * K @ K


def _same_hyp(x: dict[str, np.ndarray], y: dict[str, np.ndarray]) -> bool:
    return x.keys() == y.keys() and all(np.allclose(x[k], y[k]) for k in x)
