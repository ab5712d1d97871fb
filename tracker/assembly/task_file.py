"""Task files: parts, connections, structures and sentence tasks (YAML, validated with pydantic).

Format (``static/tasks/*.yaml``)::

    id: guess-structures            # unique id
    title: Guess which structure     # shown to the user
    mode: guess                      # guidance | guess | learning
    units: edges                     # unit of connection positions: "edges" (cube edges, default) or "m"
    edge: 0.036                      # cube edge in metres (default tracker.geometry.parts.CUBE_EDGE)
    parts:
      - {name: red, shape: box, colour: red}          # box size defaults to a cube of edge ``edge``
      - {name: rod, shape: mesh, mesh: rod.obj, colour: [200, 30, 30]}
    structures:
      - name: T-tower
        connections:                 # pose of `second` in `first`'s body frame (fundamental poses)
          - {first: red, second: green, p: [1, 0, 0], q: [0, 0, 0, 1]}
        plan: [red, green]           # guidance only: the order in which parts are placed
    sentences:                       # learning only
      - source_sentence: Μένω στον πρώτο όροφο
        words: [Vivo, en, el, primer, piso]
        distractors: [casa, primo]

Positions ``p`` of connections are in cube edges by default (``units: edges``) or metres (``units: m``);
quaternions are Hamilton ``[x, y, z, w]`` and default to the identity. Errors raised by :func:`load_task`
are :class:`TaskFileError` (a ``ValueError``) whose message names the file, the line and the field.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from tracker.geometry.parts import CUBE_EDGE, PRESET_COLORS, PartSpec
from tracker.geometry.pose import Pose


class TaskFileError(ValueError):
    """A task file (or task document) is invalid; ``errors`` lists ``(line or None, field path, message)``."""

    def __init__(self, source: str, errors: list[tuple[int | None, str, str]]):
        self.source = source
        self.errors = errors
        lines = []
        for line, loc, msg in errors:
            where = f"{source}:{line}" if line is not None else source
            lines.append(f"{where}: {loc}: {msg}" if loc else f"{where}: {msg}")
        super().__init__("invalid task file\n  " + "\n  ".join(lines))


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PartModel(_Strict):
    """A part: ``shape`` box (``size`` in metres, default a cube) or mesh (``mesh`` path relative to the file)."""

    name: str = Field(min_length=1)
    shape: Literal["box", "mesh"] = "box"
    size: tuple[float, float, float] | None = None
    mesh: str | None = None
    mesh_scale: float = 1.0
    colour: str | tuple[int, int, int] | None = None

    @field_validator("colour")
    @classmethod
    def _known_colour(cls, v):
        if isinstance(v, str) and v not in PRESET_COLORS:
            raise ValueError(f"unknown colour {v!r}; use one of {', '.join(PRESET_COLORS)} or [r, g, b]")
        if isinstance(v, tuple) and not all(0 <= c <= 255 for c in v):
            raise ValueError("RGB colour components must be in 0..255")
        return v

    @model_validator(mode="after")
    def _shape_fields(self):
        if self.shape == "mesh" and not self.mesh:
            raise ValueError("a mesh part needs 'mesh' (path to an OBJ/PLY/STL file)")
        if self.shape == "box" and self.mesh:
            raise ValueError("a box part cannot have 'mesh'; set shape: mesh")
        if self.size is not None and min(self.size) <= 0:
            raise ValueError("size must be three positive lengths in metres")
        return self

    def to_partspec(self, edge: float = CUBE_EDGE, base_dir: Path | None = None) -> PartSpec:
        rgb = PRESET_COLORS[self.colour] if isinstance(self.colour, str) else self.colour
        if self.shape == "mesh":
            mesh = Path(self.mesh)
            if base_dir is not None and not mesh.is_absolute():
                mesh = base_dir / mesh
            return PartSpec(self.name, box=None, mesh=str(mesh), mesh_scale=self.mesh_scale, color=rgb)
        size = self.size or (edge, edge, edge)
        return PartSpec(self.name, box=tuple(float(s) for s in size), color=rgb)


class ConnectionModel(_Strict):
    """Fundamental pose of ``second`` in ``first``'s body frame: ``p`` (task ``units``), ``q`` [x, y, z, w]."""

    first: str
    second: str
    p: tuple[float, float, float]
    q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    @field_validator("q")
    @classmethod
    def _unit_quat(cls, v):
        n = float(np.linalg.norm(v))
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quaternion must have unit length (got norm {n:.4f})")
        return v

    @model_validator(mode="after")
    def _distinct(self):
        if self.first == self.second:
            raise ValueError(f"a connection needs two different parts (got {self.first!r} twice)")
        return self


class StructureModel(_Strict):
    """A target structure: its connections and (guidance) the order in which parts are placed."""

    name: str = Field(min_length=1)
    title: str | None = None
    connections: list[ConnectionModel] = Field(min_length=1)
    plan: list[str] | None = None


MAX_SENTENCE_CHARS = 500
MAX_WORD_CHARS = 80
MAX_WORDS = 40
"""Bounds of a sentence task (characters of the sentence and of one word, words per list)."""
_CONTROL_CHARS = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


class SentenceTask(_Strict):
    """A learning-mode sentence: the source sentence and the Spanish words in their correct order.

    ``alternatives`` lists other accepted full orders (each a permutation of ``words``); ``distractors``
    are words put on extra cubes (ignored by the evaluation). Used by the teacher editor as well.
    """

    id: str | None = Field(None, max_length=80)
    source_sentence: str = Field(min_length=1, max_length=MAX_SENTENCE_CHARS)
    source_language: str = Field("el", max_length=16)
    target_language: str = Field("es", max_length=16)
    words: list[Annotated[str, Field(max_length=MAX_WORD_CHARS)]] = Field(min_length=2, max_length=MAX_WORDS)
    alternatives: list[list[str]] = Field(default_factory=list, max_length=MAX_WORDS)
    distractors: list[Annotated[str, Field(max_length=MAX_WORD_CHARS)]] = Field(
        default_factory=list, max_length=MAX_WORDS
    )

    @field_validator("source_sentence")
    @classmethod
    def _sentence_is_text(cls, v: str) -> str:
        if _CONTROL_CHARS.search(v):
            raise ValueError("the sentence contains control characters (such as NUL)")
        if not v.strip():
            raise ValueError("the sentence is blank")
        return v.strip()

    @field_validator("words", "distractors")
    @classmethod
    def _non_blank(cls, v):
        for i, w in enumerate(v):
            if not w.strip():
                raise ValueError(f"word {i + 1} is empty")
            if _CONTROL_CHARS.search(w):
                raise ValueError(f"word {i + 1} contains control characters (such as NUL)")
        return [w.strip() for w in v]

    @model_validator(mode="after")
    def _alternatives_are_permutations(self):
        for i, alt in enumerate(self.alternatives):
            if sorted(alt) != sorted(self.words):
                raise ValueError(
                    f"alternatives[{i}] must use exactly the words {self.words} in another order, got {alt}"
                )
        return self

    def accepted_orders(self) -> list[list[str]]:
        """The main order followed by the distinct alternatives."""
        out = [list(self.words)]
        for alt in self.alternatives:
            if alt not in out:
                out.append(list(alt))
        return out


class TaskModel(_Strict):
    """A whole task file (see the module docstring)."""

    id: str = Field(min_length=1)
    title: str | None = None
    description: str | None = None
    mode: Literal["guidance", "guess", "learning"]
    units: Literal["edges", "m"] = "edges"
    edge: float = Field(default=CUBE_EDGE, gt=0)
    parts: list[PartModel] = Field(min_length=1)
    structures: list[StructureModel] = Field(default_factory=list)
    sentences: list[SentenceTask] = Field(default_factory=list)
    parameters: dict[str, float] = Field(default_factory=dict)

    # ------------------------------------------------------------------ helpers
    def part_specs(self, base_dir: Path | None = None) -> list[PartSpec]:
        return [p.to_partspec(self.edge, base_dir) for p in self.parts]

    def scale(self) -> float:
        """Metres per unit of connection positions."""
        return self.edge if self.units == "edges" else 1.0

    def connection_pose(self, c: ConnectionModel) -> Pose:
        """Desired pose of ``c.second`` in ``c.first``'s frame, metres."""
        return Pose(np.asarray(c.p, float) * self.scale(), np.asarray(c.q, float))

    def structure(self, name: str | None = None) -> StructureModel:
        if not self.structures:
            raise ValueError(f"task {self.id!r} has no structures")
        if name is None:
            return self.structures[0]
        for s in self.structures:
            if s.name == name:
                return s
        raise ValueError(f"task {self.id!r} has no structure {name!r} (has {[s.name for s in self.structures]})")

    def semantic_errors(self) -> list[tuple[tuple, str]]:
        """Cross-field problems as ``(location, message)``: duplicates, unknown parts, sizes, plans."""
        errs: list[tuple[tuple, str]] = []
        names: dict[str, int] = {}
        for i, p in enumerate(self.parts):
            if p.name in names:
                errs.append((("parts", i, "name"), f"duplicate part name {p.name!r} (also parts[{names[p.name]}])"))
            names.setdefault(p.name, i)
        snames: dict[str, int] = {}
        for si, s in enumerate(self.structures):
            if s.name in snames:
                errs.append((("structures", si, "name"), f"duplicate structure name {s.name!r}"))
            snames.setdefault(s.name, si)
            seen_pairs: set[frozenset] = set()
            for ci, c in enumerate(s.connections):
                for fld in ("first", "second"):
                    v = getattr(c, fld)
                    if v not in names:
                        errs.append(
                            (("structures", si, "connections", ci, fld), f"unknown part {v!r} (parts: {list(names)})")
                        )
                pair = frozenset((c.first, c.second))
                if pair in seen_pairs:
                    errs.append((("structures", si, "connections", ci), f"duplicate connection {c.first}–{c.second}"))
                seen_pairs.add(pair)
            if s.plan is not None:
                used = {c.first for c in s.connections} | {c.second for c in s.connections}
                for pi, pn in enumerate(s.plan):
                    if pn not in names:
                        errs.append((("structures", si, "plan", pi), f"unknown part {pn!r}"))
                if len(set(s.plan)) != len(s.plan):
                    errs.append((("structures", si, "plan"), "a part appears twice in the plan"))
                elif set(s.plan) != used:
                    msg = f"plan must list exactly the structure's parts {sorted(used)}"
                    errs.append((("structures", si, "plan"), msg))
                else:
                    placed = {s.plan[0]}
                    for pi, pn in enumerate(s.plan[1:], start=1):
                        if not any(pair == frozenset((pn, q)) for q in placed for pair in seen_pairs):
                            errs.append(
                                (("structures", si, "plan", pi), f"{pn!r} is not connected to an earlier plan part")
                            )
                        placed.add(pn)
        if self.mode in ("guidance", "guess") and not self.structures:
            errs.append((("structures",), f"a {self.mode} task needs at least one structure"))
        if self.mode == "guidance":
            for si, s in enumerate(self.structures):
                if s.plan is None:
                    errs.append((("structures", si), "a guidance structure needs a 'plan' (order of parts)"))
        if self.mode == "learning":
            if not self.sentences:
                errs.append((("sentences",), "a learning task needs at least one sentence"))
            for i, sen in enumerate(self.sentences):
                if len(sen.words) > len(self.parts):
                    errs.append(
                        (
                            ("sentences", i, "words"),
                            f"sentence has {len(sen.words)} words but the task has only {len(self.parts)} cubes",
                        )
                    )
        return errs


# ---------------------------------------------------------------------------- YAML with line numbers
def _node_line(root: yaml.Node | None, loc: tuple) -> int | None:
    """1-based line of the YAML node at ``loc`` (the deepest existing ancestor when ``loc`` is missing)."""
    node = root
    line = node.start_mark.line + 1 if node is not None else None
    for key in loc:
        if isinstance(node, yaml.MappingNode):
            nxt = None
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode) and k.value == str(key):
                    nxt = v
                    line = k.start_mark.line + 1
                    break
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and 0 <= key < len(node.value):
            nxt = node.value[key]
        else:
            nxt = None
        if nxt is None:
            break
        node = nxt
        line = node.start_mark.line + 1
    return line


def _loc_str(loc: tuple) -> str:
    out = ""
    for k in loc:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out


def _clean_loc(loc: tuple) -> tuple:
    """Drop pydantic's union/function tags (e.g. ``'tuple[int, int, int]'``) from an error location."""
    return tuple(k for k in loc if isinstance(k, int) or ("[" not in k and not k.startswith("function-")))


def parse_task(text: str, source: str = "<task>", base_dir: Path | None = None) -> TaskModel:
    """Parse and validate a task document (YAML or JSON text). Raises :class:`TaskFileError`."""
    try:
        root = yaml.compose(text)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise TaskFileError(source, [(line, "", f"YAML syntax error: {getattr(exc, 'problem', exc)}")]) from None
    if not isinstance(data, dict):
        raise TaskFileError(source, [(1, "", "a task file must be a mapping (id, mode, parts, ...)")])
    try:
        task = TaskModel.model_validate(data)
    except ValidationError as exc:
        errors = []
        for e in exc.errors():
            loc = _clean_loc(tuple(e["loc"]))
            errors.append((_node_line(root, loc), _loc_str(loc), e["msg"].removeprefix("Value error, ")))
        raise TaskFileError(source, errors) from None
    sem = task.semantic_errors()
    if sem:
        raise TaskFileError(source, [(_node_line(root, loc), _loc_str(loc), msg) for loc, msg in sem])
    return task


def load_task(path: str | Path) -> TaskModel:
    """Load a task file. Raises :class:`TaskFileError` (line and field named) or ``OSError``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"task file not found: {path}")
    return parse_task(path.read_text(encoding="utf-8"), source=str(path), base_dir=path.parent)


def task_to_yaml(task: TaskModel) -> str:
    """YAML text of a task (round-trips through :func:`parse_task`)."""
    data: dict[str, Any] = task.model_dump(mode="json", exclude_none=True)
    return yaml.safe_dump(data, allow_unicode=True, sort_keys=False)
