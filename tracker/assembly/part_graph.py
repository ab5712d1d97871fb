"""The part graph G_P = (P, C) of a structure (spec section 5.1) and its layout in the structure frame.

The structure frame has its origin at the first part's centre, y up along the table normal; every part's
fundamental orientation is obtained by composing the connections' desired relative poses from the
first part (breadth-first). Positions are metres.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from tracker.assembly.connection_monitor import ConnectionSpec
from tracker.geometry.pose import Pose


@dataclass
class PartGraph:
    """Undirected graph: nodes = part names, edges = desired connections (index into ``connections``)."""

    parts: list[str]
    connections: list[ConnectionSpec]

    def __post_init__(self) -> None:
        self.adjacency: dict[str, list[tuple[str, int]]] = {p: [] for p in self.parts}
        for k, c in enumerate(self.connections):
            for n in (c.first, c.second):
                if n not in self.adjacency:
                    raise ValueError(f"connection {c.first}–{c.second}: part {n!r} is not in the part graph")
            self.adjacency[c.first].append((c.second, k))
            self.adjacency[c.second].append((c.first, k))

    @staticmethod
    def from_connections(connections: list[ConnectionSpec]) -> PartGraph:
        parts: list[str] = []
        for c in connections:
            for n in (c.first, c.second):
                if n not in parts:
                    parts.append(n)
        return PartGraph(parts, list(connections))

    def edges_between(self, group_a: set[str], group_b: set[str]) -> list[int]:
        """Indices of connections joining a part of ``group_a`` to a part of ``group_b``."""
        return [k for k, c in enumerate(self.connections) if (c.first in group_a and c.second in group_b)
                or (c.first in group_b and c.second in group_a)]

    def is_connected(self, group: set[str]) -> bool:
        """Whether ``group`` induces a connected subgraph."""
        if not group:
            return False
        start = next(iter(group))
        seen, todo = {start}, [start]
        while todo:
            p = todo.pop()
            for q, _ in self.adjacency[p]:
                if q in group and q not in seen:
                    seen.add(q)
                    todo.append(q)
        return seen == group

    def layout(self) -> dict[str, Pose]:
        """Fundamental pose of every part in the structure frame (first part at the origin)."""
        root = self.parts[0]
        out = {root: Pose()}
        queue = deque([root])
        while queue:
            p = queue.popleft()
            for q, k in self.adjacency[p]:
                if q in out:
                    continue
                c = self.connections[k]
                rel = Pose.from_rt(c.R_des, c.p_des)  # second in first's frame
                out[q] = out[p] @ (rel if c.first == p else rel.inverse())
                queue.append(q)
        missing = [p for p in self.parts if p not in out]
        if missing:
            raise ValueError(f"parts {missing} are not connected to {root!r}")
        return out

    def heights(self, edge: float) -> dict[str, int]:
        """Integer level (in part edges above the lowest part) of each part, from :meth:`layout`."""
        ys = {p: pose.t[1] for p, pose in self.layout().items()}
        lo = min(ys.values())
        return {p: int(round((y - lo) / edge)) for p, y in ys.items()}

    def supports(self, edge: float) -> dict[str, str | None]:
        """For each part, the part directly below it (``None`` when it rests on the table)."""
        lay = self.layout()
        lo = min(p.t[1] for p in lay.values())
        out: dict[str, str | None] = {}
        for p, pose in lay.items():
            if pose.t[1] - lo < 0.5 * edge:
                out[p] = None
                continue
            below = pose.t - np.array([0.0, edge, 0.0])
            cand = [q for q, qp in lay.items() if np.linalg.norm(qp.t - below) < 0.25 * edge]
            out[p] = cand[0] if cand else None
        return out
