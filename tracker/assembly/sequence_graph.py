"""The sequence graph G_X of stable sub-assemblies (spec section 5.2): plans as paths, next steps.

A node is a partition of the parts into blocks; each block is connected in the part graph and stable:
every part that is higher than the lowest part of its block rests on the part directly below it, and that
part is in the same block (a cube rests on the table or on another cube). An edge joins two blocks through
at least one connection. ``X_1`` = all parts separate; ``X_M`` = the assembled structure.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from tracker.assembly.part_graph import PartGraph

State = frozenset  # frozenset of frozensets of part names


def _partitions(items: list[str]) -> Iterator[list[set[str]]]:
    if not items:
        yield []
        return
    first, rest = items[0], items[1:]
    for part in _partitions(rest):
        yield [{first}, *part]
        for i in range(len(part)):
            yield [*part[:i], part[i] | {first}, *part[i + 1 :]]


@dataclass
class SequenceGraph:
    """Nodes = stable sub-assembly states; ``edges[X]`` = list of ``(Y, connection indices joining)``."""

    graph: PartGraph
    edge: float

    def __post_init__(self) -> None:
        self._heights = self.graph.heights(self.edge)
        self._support = self.graph.supports(self.edge)
        self.nodes: list[State] = []
        for blocks in _partitions(list(self.graph.parts)):
            if all(self.graph.is_connected(b) and self.stable(b) for b in blocks):
                self.nodes.append(State(frozenset(b) for b in blocks))
        node_set = set(self.nodes)
        self.edges: dict[State, list[tuple[State, list[int]]]] = {x: [] for x in self.nodes}
        for x in self.nodes:
            blocks = list(x)
            for i in range(len(blocks)):
                for j in range(i + 1, len(blocks)):
                    joins = self.graph.edges_between(set(blocks[i]), set(blocks[j]))
                    if not joins:
                        continue
                    y = State([b for k, b in enumerate(blocks) if k not in (i, j)] + [blocks[i] | blocks[j]])
                    if y in node_set:
                        self.edges[x].append((y, joins))

    def stable(self, block: set[str]) -> bool:
        """Every part above the block's lowest level rests on a part of the block (or the block has a base)."""
        lo = min(self._heights[p] for p in block)
        for p in block:
            if self._heights[p] > lo:
                below = self._support[p]
                if below is None or below not in block:
                    return False
        return True

    @property
    def start(self) -> State:
        return State(frozenset([p]) for p in self.graph.parts)

    @property
    def goal(self) -> State:
        return State([frozenset(self.graph.parts)])

    def state_of(self, established: list[bool]) -> State:
        """The partition induced by the established connections (blocks = connected components)."""
        comp = {p: {p} for p in self.graph.parts}
        for k, ok in enumerate(established):
            if ok:
                c = self.graph.connections[k]
                merged = comp[c.first] | comp[c.second]
                for p in merged:
                    comp[p] = merged
        return State({frozenset(b) for b in comp.values()})

    def next_steps(self, state: State) -> list[tuple[State, list[int]]]:
        """Feasible transitions from ``state`` (empty when the state is not a stable node)."""
        return self.edges.get(state, [])

    def plan_path(self, order: list[str]) -> list[State]:
        """States X_1 … X_M visited when the parts are added one by one in ``order`` (raises if unstable)."""
        path = [self.start]
        placed: set[str] = {order[0]}
        for p in order[1:]:
            placed = placed | {p}
            st = State([frozenset(placed)] + [frozenset([q]) for q in self.graph.parts if q not in placed])
            if st not in self.edges:
                raise ValueError(f"plan step adding {p!r} gives an unstable or disconnected sub-assembly")
            path.append(st)
        return path

    def count_paths(self) -> int:
        """Number of distinct paths from X_1 to X_M (the free-order tasks allow all of them)."""
        memo: dict[State, int] = {}

        def n(x: State) -> int:
            if x == self.goal:
                return 1
            if x not in memo:
                memo[x] = sum(n(y) for y, _ in self.edges[x])
            return memo[x]

        return n(self.start)
