"""Learning mode — building a Spanish sentence from word-carrying cubes (spec section 11.3).

* Word → cube assignment: random and seeded (``numpy.random.default_rng(seed)``): the cubes are shuffled,
  the first ``len(words)`` get the words in order, the next ones get the distractor words (shuffled);
  remaining cubes carry nothing. An explicit ``assignment`` ``{cube: word}`` may be given instead (the
  evaluation uses the simulator's fixed one).
* Connections: for each accepted order (the sentence and its alternatives) the cubes of consecutive words
  are joined by a connection ``(a, 0, 0)`` in the first cube's frame (cube symmetry handled by the monitor);
  one monitor per accepted order.
* Reading: face-to-face contacts between cubes (any pair) are detected with N_checks; a contact counts for
  the row when the two cubes are side by side (vertical offset below half an edge) and the row runs along
  the user's left–right axis (|Δx| ≥ |Δz| in the table frame). The row is read with table x increasing,
  i.e. left → right for the user (image x increasing). The row containing the most word cubes is read.
* Verdicts per word position against the accepted order that matches most positions; ``complete`` only when
  the row reads exactly an accepted order and all of that order's connections are established. Progress
  counts the words in their right place. Once complete, the state (with the verdict) is kept until
  :meth:`LearningMode.reset` — the next round — even when the row is taken apart afterwards.
* The word list shown to the user (``words``) is in a seeded shuffled order, never the sentence's own.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from tracker.assembly.connection_monitor import AdjacencyDetector, AssemblyParams, ConnectionMonitor, ConnectionSpec
from tracker.assembly.mode_state import ModeState
from tracker.assembly.modes.base import Mode
from tracker.assembly.task_file import SentenceTask, TaskModel
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


def assign_words(sentence: SentenceTask, cubes: list[str], seed: int) -> dict[str, str]:
    """Seeded random ``{cube: word}``: sentence words first, then distractors on extra cubes."""
    if len(sentence.words) > len(cubes):
        raise ValueError(f"sentence has {len(sentence.words)} words but only {len(cubes)} cubes are available")
    rng = np.random.default_rng(seed)
    order = [cubes[i] for i in rng.permutation(len(cubes))]
    out = {c: w for c, w in zip(order, sentence.words, strict=False)}
    extra = order[len(sentence.words) :]
    distractors = [sentence.distractors[i] for i in rng.permutation(len(sentence.distractors))]
    for c, w in zip(extra, distractors, strict=False):
        out[c] = w
    return out


def _cubes_for_order(order: list[str], word_cubes: list[tuple[str, str]]) -> list[str]:
    """Cube sequence spelling ``order`` using the word cubes (duplicate words take the next free cube)."""
    free = list(word_cubes)
    out = []
    for w in order:
        i = next(i for i, (_, ww) in enumerate(free) if ww == w)
        out.append(free.pop(i)[0])
    return out


class LearningMode(Mode):
    name = "learning"

    def __init__(self, task: TaskModel, parts: Iterable[PartSpec] | None = None, params: AssemblyParams | None = None,
                 sentence: SentenceTask | int | str | None = None, seed: int = 0,
                 assignment: dict[str, str] | None = None, **overrides):
        super().__init__(task, parts, params, **overrides)
        self.sentence = self._pick_sentence(task, sentence, seed)
        cubes = [p.name for p in self.parts if p.is_cube]
        if assignment is None:
            assignment = assign_words(self.sentence, cubes, seed)
        else:
            unknown = [c for c in assignment if c not in cubes]
            if unknown:
                raise ValueError(f"assignment names cubes {unknown} that are not among {cubes}")
        self.assignment = dict(assignment)
        # Word cubes in sentence order; the remaining assigned cubes carry distractors.
        remaining = dict(self.assignment)
        self.word_cubes: list[tuple[str, str]] = []
        for w in self.sentence.words:
            c = next((c for c, ww in remaining.items() if ww == w), None)
            if c is None:
                raise ValueError(f"no cube carries the word {w!r}")
            self.word_cubes.append((c, w))
            remaining.pop(c)
        self.distractor_cubes = remaining
        self.orders = self.sentence.accepted_orders()
        edge = task.edge
        self.order_cubes = [_cubes_for_order(o, self.word_cubes) for o in self.orders]
        self._monitors = []
        for cubes_seq in self.order_cubes:
            specs = [ConnectionSpec(a, b, np.array([edge, 0.0, 0.0]), np.eye(3))
                     for a, b in zip(cubes_seq[:-1], cubes_seq[1:], strict=True)]
            self._monitors.append(ConnectionMonitor(self.parts, specs, self.params, detect_unexpected=False))
        self.adjacency = AdjacencyDetector([p for p in self.parts if p.is_cube], self.params)
        self.edge = edge
        self.display_words = self._shuffled_words(seed)
        self._completed: ModeState | None = None

    def _shuffled_words(self, seed: int) -> list[dict]:
        """``[{word, cube, is_distractor}]`` in a seeded order that is not the sentence's (when there is another)."""
        words = [{"word": w, "cube": c, "is_distractor": False} for c, w in self.word_cubes]
        words += [{"word": w, "cube": c, "is_distractor": True} for c, w in self.distractor_cubes.items()]
        rng = np.random.default_rng(seed + 7919)  # not the assignment's stream
        sentence = [w for _, w in self.word_cubes]
        for _ in range(20):
            order = [words[i] for i in rng.permutation(len(words))]
            if [d["word"] for d in order if not d["is_distractor"]] != sentence:
                return order
        return order

    @staticmethod
    def _pick_sentence(task: TaskModel, sentence, seed: int) -> SentenceTask:
        if isinstance(sentence, SentenceTask):
            return sentence
        if not task.sentences:
            raise ValueError(f"task {task.id!r} has no sentences")
        if sentence is None:
            return task.sentences[int(np.random.default_rng(seed).integers(len(task.sentences)))]
        if isinstance(sentence, int):
            if not 0 <= sentence < len(task.sentences):
                raise ValueError(f"task {task.id!r} has {len(task.sentences)} sentences; index {sentence} is invalid")
            return task.sentences[sentence]
        for s in task.sentences:
            if s.id == sentence:
                return s
        raise ValueError(f"task {task.id!r} has no sentence {sentence!r}")

    def monitors(self) -> list[ConnectionMonitor]:
        return self._monitors

    def reset(self) -> None:
        super().reset()
        self.adjacency.reset()
        self._completed = None

    # ------------------------------------------------------------------ reading the row
    def read_row(self) -> list[str]:
        """Cubes of the row with the most word cubes, left → right for the user (table x increasing)."""
        right: dict[str, tuple[str, float]] = {}
        left: dict[str, tuple[str, float]] = {}
        for st in self.adjacency.connected():
            d = st.offset_table
            if d is None or abs(d[1]) > 0.5 * self.edge or abs(d[0]) < abs(d[2]):
                continue
            a, b = (st.first, st.second) if d[0] > 0 else (st.second, st.first)  # a is left of b
            err = abs(abs(d[0]) - self.edge) + abs(d[2])
            if (a not in right or err < right[a][1]) and (b not in left or err < left[b][1]):
                right[a] = (b, err)
                left[b] = (a, err)
        rows = []
        for start in right:
            if start in left and left[start][0] in right and right[left[start][0]][0] == start:
                continue  # not the leftmost cube
            row, seen = [start], {start}
            while row[-1] in right and right[row[-1]][0] not in seen:
                nxt = right[row[-1]][0]
                if left.get(nxt, (None,))[0] != row[-1]:
                    break
                row.append(nxt)
                seen.add(nxt)
            rows.append(row)
        words = {c for c, _ in self.word_cubes}
        if not rows:
            return []
        return max(rows, key=lambda r: (sum(c in words for c in r), -len(r)))

    def update(self, t: float, poses: dict[str, Pose], table_to_camera: Pose) -> ModeState:
        events = self._update_monitors(t, poses, table_to_camera)
        events += [e.to_dict() for e in self.adjacency.update(t, poses, table_to_camera)]
        if self._completed is not None:  # the verdict stays until the next round (reset)
            done = self._completed
            state = ModeState(self.name, self.task.id, t, done.instruction, done.done, done.total, True,
                              connections=done.connections, events=events, extra=done.extra, unit=done.unit)
            self.last_state = state
            return state
        row = self.read_row()
        placed_words = [self.assignment.get(c) for c in row]
        best_i, best_hits = 0, -1
        for i, order in enumerate(self.orders):
            hits = sum(1 for j, w in enumerate(order) if j < len(placed_words) and placed_words[j] == w)
            hits = hits * 100 + self._monitors[i].n_established()
            if hits > best_hits:
                best_i, best_hits = i, hits
        order = self.orders[best_i]
        verdicts = []
        for j, w in enumerate(order):
            placed = placed_words[j] if j < len(placed_words) else None
            verdicts.append({"position": j + 1, "expected": w, "placed": placed, "correct": placed == w})
        mon = self._monitors[best_i]
        reads_ok = placed_words == list(order)
        complete = reads_ok and mon.n_established() == len(mon.connections)
        src = self.sentence.source_sentence
        if complete:
            instruction = f"¡Muy bien! «{' '.join(order)}» is correct."
        elif len(row) >= len(order) and not reads_ok:
            instruction = f"Not quite — check the word order for «{src}»."
        else:
            instruction = f"Build the Spanish sentence for «{src}»."
        conns = mon.to_list()
        n_right = sum(1 for v in verdicts if v["correct"])
        state = ModeState(
            self.name, self.task.id, t, instruction, n_right, len(order), complete,
            connections=conns, events=events,
            extra={"sentence": src, "source_language": self.sentence.source_language, "sentence_id": self.sentence.id,
                   "words": list(self.display_words), "assignment": dict(self.assignment), "row": row,
                   "verdicts": verdicts, "accepted_order": best_i},
            unit="words",
        )
        if complete:
            self._completed = state
        self.last_state = state
        return state
