"""Guidance mode (spec section 11.1): one path through the sequence graph, one step at a time.

Each plan step places one part next to an already placed part (its *anchor*) through one connection of the
structure. The current step is the first one whose connection is not established; it is confirmed when its
connection is established. With ``check_ahead=False`` only the current step's connection is checked (plus
the established ones, which may break), as in the thesis; by default (``check_ahead=True``, a documented
deviation) the later steps' connections are checked as well, so that one missed confirmation does not
block the rest of the session (the instruction still names the first unconfirmed step).

The next step is given as text and as data: the camera-frame target pose of the part, computed from the
anchor's pose with its cube-symmetry choice (the stored prior once the anchor is connected; before that,
the cube rotation that puts its y axis up and its x axis along the table x axis, i.e. left → right for the
user). A warning is shown when a placement does
not match the plan (a contact no connection asked for, or a confirmed step that came apart).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from tracker.assembly.connection_monitor import AssemblyParams, ConnectionMonitor, specs_from_structure
from tracker.assembly.mode_state import ModeState
from tracker.assembly.modes.base import Mode, direction_words
from tracker.assembly.part_graph import PartGraph
from tracker.assembly.sequence_graph import SequenceGraph
from tracker.assembly.task_file import TaskModel
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import cube_group


@dataclass
class Step:
    part: str
    anchor: str
    connection: int  # index into the structure's connections


def _upright_rotation(R: np.ndarray, table_to_camera: Pose) -> np.ndarray:
    """Q ∈ G making the corrected orientation R Qᵀ closest to the table frame (y up, x along table x)."""
    target = table_to_camera.R  # table axes in the camera frame
    G = cube_group()
    score = np.einsum("ij,nij->n", target.T @ R, G)  # trace(targetᵀ R Sᵀ)
    return G[int(np.argmax(score))]


class GuidanceMode(Mode):
    name = "guidance"

    def __init__(self, task: TaskModel, parts: Iterable[PartSpec] | None = None, params: AssemblyParams | None = None,
                 structure: str | None = None, check_ahead: bool = True, **overrides):
        super().__init__(task, parts, params, **overrides)
        self.check_ahead = check_ahead
        self.structure = task.structure(structure)
        if not self.structure.plan:
            raise ValueError(f"structure {self.structure.name!r} of task {task.id!r} has no plan")
        self.specs = specs_from_structure(task, self.structure)
        self.graph = PartGraph.from_connections(self.specs)
        self.sequence = SequenceGraph(self.graph, task.edge)
        self.path = self.sequence.plan_path(self.structure.plan)
        plan = self.structure.plan
        self.steps: list[Step] = []
        for i, part in enumerate(plan[1:], start=1):
            for k, c in enumerate(self.specs):
                other = c.second if c.first == part else c.first if c.second == part else None
                if other is not None and other in plan[:i]:
                    self.steps.append(Step(part, other, k))
                    break
        self.monitor = ConnectionMonitor(self.parts, self.specs, self.params)
        self._done_before: set[int] = set()

    def monitors(self) -> list[ConnectionMonitor]:
        return [self.monitor]

    def reset(self) -> None:
        super().reset()
        self._done_before = set()

    def current_step(self) -> int:
        """Index of the first step whose connection is not established (``len(steps)`` when complete)."""
        est = self.monitor.established
        for i, s in enumerate(self.steps):
            if not est[s.connection]:
                return i
        return len(self.steps)

    def target_pose(self, step: Step, poses: dict[str, Pose], table_to_camera: Pose) -> Pose | None:
        """Camera-frame pose where ``step.part`` should go (fundamental orientation), or ``None``."""
        anchor = poses.get(step.anchor)
        if anchor is None:
            return None
        F = self.monitor.symmetry.fundamental(step.anchor)
        is_cube = next(p for p in self.parts if p.name == step.anchor).is_cube
        if F is None:
            Q = _upright_rotation(anchor.R, table_to_camera) if is_cube else np.eye(3)
            F = anchor.R @ Q.T
        anchor_fund = Pose.from_rt(F, anchor.t)
        c = self.specs[step.connection]
        rel = Pose.from_rt(c.R_des, c.p_des)
        return anchor_fund @ (rel if c.first == step.anchor else rel.inverse())

    def update(self, t: float, poses: dict[str, Pose], table_to_camera: Pose) -> ModeState:
        i = self.current_step()
        ahead = self.steps[i:] if self.check_ahead else self.steps[i : i + 1]
        active = {s.connection for s in ahead}
        n0 = len(self.monitor.events)
        self.monitor.update(t, poses, table_to_camera, active=active)
        events = [e.to_dict() for e in self.monitor.events[n0:]]
        est = self.monitor.established
        done = sum(est[s.connection] for s in self.steps)
        i = self.current_step()
        complete = i == len(self.steps)
        warning = None
        broken = [s for j, s in enumerate(self.steps) if j in self._done_before and not est[s.connection]]
        self._done_before |= {j for j, s in enumerate(self.steps) if est[s.connection]}
        if broken:
            s = broken[0]
            warning = f"The {s.part} part came apart from the {s.anchor} part — put it back."
        unexpected = self.monitor.unexpected()
        if unexpected and not complete:
            u = unexpected[0]
            warning = (f"The {u.first} and {u.second} parts touch, but the plan does not join them there"
                       " — check the placement.")
        next_step = None
        if complete:
            instruction = "Done — the structure is complete."
        else:
            step = self.steps[i]
            target = self.target_pose(step, poses, table_to_camera)
            where = "next to"
            if target is not None and step.anchor in poses:
                where = direction_words(self._table_offset(table_to_camera, poses[step.anchor], target))
            instruction = (f"Step {i + 1} of {len(self.steps)}: "
                           f"place the {step.part} part {where} the {step.anchor} part.")
            next_step = {
                "index": i,
                "part": step.part,
                "anchor": step.anchor,
                "direction": where,
                "target_pose": None if target is None else target.to_dict(),
            }
        state = ModeState(
            self.name, self.task.id, t, instruction, done, len(self.steps), complete,
            connections=self.monitor.to_list(), events=events,
            extra={"structure": self.structure.name, "step": i, "next_step": next_step, "warning": warning},
            unit="steps",
        )
        self.last_state = state
        return state
