"""Guess mode — intention recognition (spec section 11.2).

Every connection of every candidate structure is checked every frame; each candidate has its own
:class:`ConnectionMonitor` (its own state vector v_c and its own cube-symmetry priors, since candidates may
define their fundamental frames differently). Candidates are ranked by the fraction of their connections
that are established (the completed count when all have the same number).

Tie-break (thesis): keep the candidate that was the unique leader at the last time step without a tie.
Chosen here when that candidate is not among the tied ones or there was no tie-free step yet: the tied
candidate with the largest summed connection score over its open connections (continuous evidence of
connections about to be made), then the order in the task file; the previous guess is kept unless another
tied candidate's evidence is larger by ``EVIDENCE_HYSTERESIS`` (no flicker between tied candidates).

The instruction names a structure only while it leads alone; while the leaders are tied it says "not sure
yet" and names them (``guess`` still holds the tie-break's choice, for the evaluation).

Confidence: leader's fraction minus the best other candidate's fraction (0 while tied, 1 when the leader is
complete and no other candidate has any connection).
"""

from __future__ import annotations

from collections.abc import Iterable

from tracker.assembly.connection_monitor import AssemblyParams, ConnectionMonitor, specs_from_structure
from tracker.assembly.mode_state import ModeState
from tracker.assembly.modes.base import Mode
from tracker.assembly.task_file import TaskModel
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

EVIDENCE_HYSTERESIS = 0.25
"""A tied candidate replaces the previous guess on evidence only when its evidence is larger by this much."""


def choose_guess(fractions: list[float], evidence: list[float], last_unique: int | None,
                 previous: int | None = None, tol: float = 1e-9) -> tuple[int, bool]:
    """Index of the guess and whether the leaders were tied (the rule in the module docstring).

    ``previous`` (the last guess) makes the evidence rule sticky: among tied candidates the previous guess
    stays unless another one's evidence exceeds its own by :data:`EVIDENCE_HYSTERESIS`.
    """
    top = max(fractions)
    tied = [i for i, f in enumerate(fractions) if f >= top - tol]
    if len(tied) == 1:
        return tied[0], False
    if last_unique is not None and last_unique in tied:
        return last_unique, True
    best = max(tied, key=lambda i: (evidence[i], -i))
    if previous is not None and previous in tied and evidence[best] < evidence[previous] + EVIDENCE_HYSTERESIS:
        return previous, True
    return best, True


class GuessMode(Mode):
    name = "guess"

    def __init__(self, task: TaskModel, parts: Iterable[PartSpec] | None = None, params: AssemblyParams | None = None,
                 **overrides):
        super().__init__(task, parts, params, **overrides)
        if len(task.structures) < 1:
            raise ValueError(f"guess task {task.id!r} needs candidate structures")
        self.structures = task.structures
        self._monitors = [
            ConnectionMonitor(self.parts, specs_from_structure(task, s), self.params, detect_unexpected=(i == 0))
            for i, s in enumerate(self.structures)
        ]
        self._last_unique: int | None = None
        self._previous: int | None = None
        self.guess_history: list[tuple[float, str]] = []

    def monitors(self) -> list[ConnectionMonitor]:
        return self._monitors

    def reset(self) -> None:
        super().reset()
        self._last_unique = None
        self._previous = None
        self.guess_history = []

    def update(self, t: float, poses: dict[str, Pose], table_to_camera: Pose) -> ModeState:
        events = self._update_monitors(t, poses, table_to_camera)
        fractions, evidence, ranking = [], [], []
        for s, m in zip(self.structures, self._monitors, strict=True):
            n, total = m.n_established(), len(m.connections)
            fractions.append(n / total)
            evidence.append(sum(st.score for st in m.status if st.state != "connected"))
            ranking.append({"structure": s.name, "title": s.title or s.name, "completed": n, "total": total,
                            "fraction": round(n / total, 4)})
        idx, tied = choose_guess(fractions, evidence, self._last_unique, self._previous)
        self._previous = idx
        if not tied:
            self._last_unique = idx
        others = [f for i, f in enumerate(fractions) if i != idx]
        confidence = max(0.0, fractions[idx] - (max(others) if others else 0.0))
        order = sorted(range(len(ranking)), key=lambda i: (i != idx, -fractions[i], i))
        guess = self.structures[idx]
        best = self._monitors[idx]
        complete = best.n_established() == len(best.connections)
        if not self.guess_history or self.guess_history[-1][1] != guess.name:
            self.guess_history.append((t, guess.name))
        if complete:
            instruction = f"You built the {guess.title or guess.name}."
        elif max(fractions) == 0:
            instruction = "Build one of the structures — I will guess which one."
        elif tied:
            leaders = [self.structures[i] for i in range(len(fractions)) if fractions[i] >= max(fractions) - 1e-9]
            names = " and ".join(s.title or s.name for s in leaders)
            instruction = f"Not sure yet — {names} fit equally well so far."
        else:
            instruction = f"I think you are building the {guess.title or guess.name}."
        conns: dict[frozenset, dict] = {}
        for m in self._monitors:
            for c in m.to_list():
                k = frozenset((c["first"], c["second"]))
                rank = {"open": 0, "near": 1, "connected": 2}[c["state"]]
                if k not in conns or rank > {"open": 0, "near": 1, "connected": 2}[conns[k]["state"]]:
                    conns[k] = c
        state = ModeState(
            self.name, self.task.id, t, instruction, best.n_established(), len(best.connections), complete,
            connections=list(conns.values()), events=events,
            extra={"ranking": [ranking[i] for i in order], "guess": guess.name, "confidence": round(confidence, 4),
                   "tied": tied},
        )
        self.last_state = state
        return state
