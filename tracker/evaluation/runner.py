"""Run one simulated session through a mode, on ground-truth+noise or tracked poses.

Pose sources:

* ``"groundtruth"``: the simulator's ground-truth poses (no rendering) plus Gaussian noise
  (σ = 3 mm per axis, 0.05 rad per rotation axis, seeded) and the true table frame;
* ``"tracked"``: each frame is rendered, colour detections (``ColorDetector``) and the table
  (``detect_table`` on the first frame) feed the depth particle filter (``MultiObjectTracker``), which is
  initialised with the first frame's true poses (as the thesis initialised manually) and receives the mode's
  connection hints every frame (Algorithm 6). Tracker preset: ``default`` unless given.

``max_time`` stops the session early (seconds; true connections after it are then counted as missed).
``frame_step`` processes every n-th frame (timestamps stay the simulator's, 30 fps); ``hints=False`` runs the
tracker without the mode's connection hints (ablation of Algorithm 6). ``hands=True`` (tracked poses only) runs the
hand tracker on the rendered frames as the pipeline does (:class:`tracker.hands.loop.HandLoop`: occluder prior for
the tracker, touching / holding after its step) and gives the mode the touched parts, so the connection gate of
hand-tracking spec §14.7 acts unless ``hand_gate=0`` is among the overrides (the gate-off arm of that comparison).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tracker.assembly.modes import build_mode
from tracker.assembly.presets import load_preset
from tracker.assembly.synthetic import jitter
from tracker.evaluation.sessions import SessionSpec
from tracker.geometry.pose import Pose

COMPLETE_GRACE = 1.0
"""A mode's "complete" counts as false when it comes more than this many seconds before the true completion
(the ±1 s tolerance of the timing metric), or names the wrong structure (guess)."""


@dataclass
class SessionResult:
    spec: SessionSpec
    poses: str
    duration: float
    frames: int
    truth_events: list[tuple[float, str, str]]  # (t, first, second) connected
    detected_events: list[tuple[float, str, str]]  # first detection of each pair
    completion_true: float | None
    completion_detected: float | None
    false_completions: int
    final_guess: str | None = None
    guess_history: list[tuple[float, str]] = field(default_factory=list)
    verdicts_correct: bool | None = None
    final_state: dict = field(default_factory=dict)
    seconds: float = 0.0
    params: dict = field(default_factory=dict)
    error: str | None = None

    def to_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k != "spec"}
        d["spec"] = self.spec.to_dict()
        return d


def _mode_kwargs(spec: SessionSpec, src, task) -> dict:
    if spec.experiment != "learning":
        return {}
    info = src.scenario
    row = [c for c, _ in sorted(info.structure.cells, key=lambda c: c[1][0])]
    sentence = task.sentences[int(spec.truth or 0)]
    assignment = dict(zip(row, sentence.words, strict=True))
    for c, w in zip(info.distractors, sentence.distractors, strict=False):
        assignment[c] = w
    return {"sentence": int(spec.truth or 0), "assignment": assignment}


def _swapped(assignment: dict[str, str], sentence_words: list[str]) -> dict[str, str]:
    """The same assignment with the cubes of the first two words exchanged (a wrong sentence)."""
    inv = {w: c for c, w in assignment.items()}
    out = dict(assignment)
    a, b = inv[sentence_words[0]], inv[sentence_words[1]]
    out[a], out[b] = assignment[b], assignment[a]
    return out


def run_session(spec: SessionSpec, poses: str = "groundtruth", overrides: dict | None = None,
                frame_step: int = 1, tracker_preset: str = "default", n_particles: int | None = None,
                noise: tuple[float, float] = (0.003, 0.05), hints: bool = True,
                max_time: float | None = None, on_frame: Callable[[int, int], None] | None = None,
                hands: bool = False) -> SessionResult:
    """Run ``spec`` and compare the mode's output with the simulator's ground truth.

    ``on_frame(i, n)``: called after each processed frame ``i`` of the session's ``n`` (progress display)."""
    from tracker.sources.simulator import FPS, SimOptions, SimulatedTable

    if poses not in ("groundtruth", "tracked"):
        raise ValueError(f"poses must be 'groundtruth' or 'tracked', got {poses!r}")
    if hands and poses != "tracked":
        raise ValueError("hand tracking needs rendered frames: use it with tracked poses")
    t_start = time.perf_counter()
    src = SimulatedTable(spec.scenario, seed=spec.seed, realtime=False,
                         options=SimOptions(speed=spec.speed, occlusion=spec.occlusion, excursions=spec.excursions))
    task = load_preset(spec.task_id)
    kwargs = _mode_kwargs(spec, src, task)
    mode = build_mode(task, parts=src.parts, seed=spec.seed, **kwargs, **(overrides or {}))
    wrong = None
    if spec.experiment == "learning":
        wrong = build_mode(task, parts=src.parts, seed=spec.seed, sentence=kwargs["sentence"],
                           assignment=_swapped(kwargs["assignment"], mode.sentence.words), **(overrides or {}))
    truth = [(e.t, e.parts[0], e.parts[1]) for e in src.events if e.type == "connected"]
    t_complete = max((t for t, _, _ in truth), default=None)
    rng = np.random.default_rng(spec.seed + 7)
    table_to_camera: Pose = src.table_to_camera
    tracker = detector = table = hand_loop = plane = None
    if poses == "tracked":
        from tracker.filter.particle_filter import MultiObjectTracker
        from tracker.filter.tracker_config import TrackerConfig
        from tracker.perception.color_detection import ColorDetector
        from tracker.perception.table_plane import detect_table

        cfg = TrackerConfig.preset(tracker_preset)
        if n_particles is not None:
            cfg = cfg.with_overrides(n_particles=n_particles)
        first = src.render(0)
        table = detect_table(first.depth, src.intrinsics)
        table_to_camera = table.table_to_camera()
        detector = ColorDetector.from_parts(src.parts)
        tracker = MultiObjectTracker(src.parts, src.intrinsics, cfg, seed=spec.seed)
        tracker.initialize(src.initial_poses)
        if hands:
            from tracker.filter.frame_context import table_normal_offset
            from tracker.hands.loop import HandLoop

            hand_loop = HandLoop(src.parts, src.intrinsics)
            plane = table_normal_offset(table)
    est = dict(src.initial_poses)
    completion_detected, false_completions, was_complete, n_frames = None, 0, False, 0
    state = None
    for i in range(0, len(src), max(1, frame_step)):
        t = i / FPS
        if max_time is not None and t > max_time:
            break
        if tracker is not None:
            frame = src.render(i)
            occluders = touched = None
            if hand_loop is not None:
                hand_loop.perceive(frame.color, frame.depth, plane, est)
                occluders, touched = hand_loop.occluder_mask(), hand_loop.touched_parts()
            est = tracker.step(frame, detector.detect(frame.color), table, occluders=occluders, touched=touched).poses
            if hand_loop is not None:
                hand_loop.update_contacts(est, frame.depth)
                mode.set_hand_contacts(hand_loop.touched_parts())
        else:
            est = jitter(src.groundtruth(i), rng, *noise)
        state = mode.update(t, est, table_to_camera)
        if tracker is not None and hints:
            tracker.set_connection_hints(mode.connection_hints())
        n_frames += 1
        if on_frame is not None:
            on_frame(i, len(src))
        complete = state.complete
        if complete and not was_complete:
            wrong_structure = spec.experiment == "guess" and state.extra.get("guess") != spec.truth
            too_early = t_complete is None or t < t_complete - COMPLETE_GRACE
            if wrong_structure or too_early:
                false_completions += 1
            elif completion_detected is None:
                completion_detected = t
        was_complete = complete
        if wrong is not None and wrong.update(t, est, table_to_camera).complete:
            false_completions += 1 if not getattr(wrong, "_flagged", False) else 0
            wrong._flagged = True
    detected: dict[frozenset, tuple[float, str, str]] = {}
    for e in mode.connection_events():
        k = frozenset((e.first, e.second))
        if e.type == "connected" and k not in detected:
            detected[k] = (e.t, e.first, e.second)
    final = state.to_dict() if state is not None else {}
    res = SessionResult(
        spec, poses, float(src.duration), n_frames, truth, sorted(detected.values()), t_complete,
        completion_detected, false_completions, params=mode.params.to_dict(), final_state=final,
    )
    if spec.experiment == "guess":
        res.final_guess = final.get("guess")
        res.guess_history = list(mode.guess_history)
    if spec.experiment == "learning":
        res.verdicts_correct = bool(final.get("complete")) and all(v["correct"] for v in final.get("verdicts", []))
    res.seconds = time.perf_counter() - t_start
    return res
