"""Learner results: what a learner did in each session, read from the mode's state after every frame.

:class:`ResultsRecorder` is a worker frame hook (:attr:`app.worker.PipelineWorker.frame_hooks`): per frame it only
compares the mode state with the previous one (a few dictionary look-ups) and appends finished steps to an
in-memory buffer; a background thread writes the buffer to the database every ``flush_interval_s`` seconds in
one transaction (:meth:`app.storage.Storage.record_results`). A failed write (database down, locked) keeps the
buffer and tries again later, so nothing is lost in an outage and the frame loop never waits for the database.

Definitions (per session; a looping source starts the task again: attempt 1, 2, …):

* **step** ``k`` (1-based) is finished when the mode's progress (``progress.done``: steps in guidance,
  connections in guess, words in their right place in learning) first reaches ``k`` in this attempt; its time
  runs from the end of the previous step (or the start of the attempt) to then. At the end of the session or
  attempt, the step being worked on is stored with the verdict ``unfinished``.
* **wrong placement**: a connection the task does not ask for was made (a monitor event ``connected`` with
  ``expected`` false; guidance and guess), or a word cube was put in a wrong position of the row (learning;
  counted when a position turns wrong).
* **hint**: the mode showed a corrective message: a new guidance warning ("… came apart …", "… the plan does not
  join them …"), or in learning the full row was read in a wrong order ("Not quite — check the word order").

Times are wall-clock seconds (``time.time()``); durations are seconds.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from app.storage import Storage, StorageError
from tracker.os_names import name_os_thread

log = logging.getLogger(__name__)

BLINK_S = 1.0
"""An unfinished step shorter than this (seconds) with no wrong placement or hint is not stored."""
MAX_BUFFERED_STEPS = 20_000
"""Step rows kept in memory while the database cannot be written; older ones are dropped (and counted) above."""


@dataclass
class _Attempt:
    """What the recorder follows within one attempt of a session."""

    round: Any
    started_at: float
    total: int = 0
    best: int = 0
    step_started_at: float = 0.0
    label: str | None = None
    wrong: int = 0
    hints: int = 0
    complete: bool = False
    warning: str | None = None
    wrong_positions: set = field(default_factory=set)
    misread: bool = False


class ResultsRecorder:
    """Follows the current session's mode state frame by frame and stores steps, wrong placements and hints."""

    def __init__(self, storage: Storage, flush_interval_s: float = 2.0) -> None:
        self.storage = storage
        self.flush_interval_s = flush_interval_s
        self._lock = threading.Lock()
        self._session: tuple[int, str | None] | None = None  # (id, mode)
        self._attempt: _Attempt | None = None
        self._attempts = 0
        self._steps: list[dict[str, Any]] = []
        self._totals: dict[int, dict[str, Any]] = {}
        self.dropped = 0
        """Step rows dropped because the database stayed unwritable too long (see :data:`MAX_BUFFERED_STEPS`)."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ sessions
    def switch(self, session_id: int | None, mode: str | None, now: float | None = None) -> None:
        """The current session ends (its unfinished step is stored) and ``session_id`` with ``mode`` begins."""
        now = time.time() if now is None else now
        with self._lock:
            self._close_attempt(now)
            self._session = (session_id, mode) if session_id is not None and mode not in (None, "none") else None
            self._attempt = None
            self._attempts = 0

    # ------------------------------------------------------------------ per frame (worker thread)
    def on_frame(self, snapshot: Any, _frame: Any = None) -> None:
        """Compare the snapshot's mode state with the last one; never raises (the frame loop must go on)."""
        try:
            self.observe(snapshot.mode, snapshot.mode_state, snapshot.source.get("round"),
                         snapshot.wall_time or time.time())
        except Exception:  # noqa: BLE001 - a recorder bug must not stop tracking
            log.exception("learner results: frame not recorded")

    def observe(self, mode: str | None, state: dict[str, Any], round_: Any, now: float) -> None:
        """One frame of ``mode`` (its ``ModeState.to_dict()``) in pipeline round ``round_`` at wall time ``now``."""
        with self._lock:
            if self._session is None or not state or mode != self._session[1]:
                return  # no session, no mode, or a frame of the pipeline before the switch
            progress = state.get("progress") or {}
            done, total = int(progress.get("done", 0)), int(progress.get("total", 0))
            a = self._attempt
            if a is None or a.round != round_:
                self._close_attempt(now)
                self._attempts += 1
                # the first frame is the baseline: what was already built counts to no one
                a = self._attempt = _Attempt(round_, now, best=done, step_started_at=now)
            if total != a.total:
                a.total = total
                self._total(self._session[0])["steps_total"] = total
            wrong = sum(1 for e in state.get("events") or () if e.get("type") == "connected"
                        and e.get("expected") is False)
            verdicts = state.get("verdicts")
            if verdicts is not None:  # learning: positions that turned wrong
                now_wrong = {v.get("position") for v in verdicts if v.get("placed") is not None
                             and not v.get("correct")}
                wrong += len(now_wrong - a.wrong_positions)
                a.wrong_positions = now_wrong
                row = state.get("row") or []
                misread = bool(now_wrong) and len(row) >= total and not state.get("complete")
                if misread and not a.misread:
                    a.hints += 1
                a.misread = misread
            warning = state.get("warning")
            if warning and warning != a.warning:
                a.hints += 1
            a.warning = warning
            a.wrong += wrong
            if a.label is None:
                a.label = self._label(state, a.best + 1)
            while done > a.best:
                a.best += 1
                self._add_step(a, a.best, "done", now)
                a.label = self._label(state, a.best + 1) if a.best < done else None
            if state.get("complete") and not a.complete:
                a.complete = True
                tot = self._total(self._session[0])
                tot.setdefault("completed_at", now)

    @staticmethod
    def _label(state: dict[str, Any], k: int) -> str | None:
        """What step ``k`` asks for: the guidance step's parts, or the learning position's word."""
        nxt = state.get("next_step")
        if isinstance(nxt, dict) and nxt.get("index") == k - 1:
            return f"{nxt.get('part')} {nxt.get('direction') or 'next to'} {nxt.get('anchor')}"
        verdicts = state.get("verdicts")
        if verdicts and 0 < k <= len(verdicts):
            return f"word {k}: {verdicts[k - 1].get('expected')}"
        return None

    def _total(self, session_id: int) -> dict[str, Any]:
        return self._totals.setdefault(session_id, {"wrong_placements": 0, "hints": 0})

    def _add_step(self, a: _Attempt, k: int, verdict: str, now: float) -> None:
        assert self._session is not None
        session_id = self._session[0]
        self._steps.append({
            "session_id": session_id, "attempt": self._attempts, "step": k, "label": a.label, "verdict": verdict,
            "started_at": a.step_started_at, "ended_at": now, "duration_s": max(0.0, now - a.step_started_at),
            "wrong_placements": a.wrong, "hints": a.hints,
        })
        tot = self._total(session_id)
        tot["wrong_placements"] += a.wrong
        tot["hints"] += a.hints
        a.wrong = a.hints = 0
        a.step_started_at = now
        if len(self._steps) > MAX_BUFFERED_STEPS:
            del self._steps[0]
            self.dropped += 1

    def _close_attempt(self, now: float) -> None:
        """Store the step being worked on as unfinished (when the attempt did not complete)."""
        a = self._attempt
        if a is None or self._session is None or a.complete:
            return
        if now - a.step_started_at < BLINK_S and a.wrong == 0 and a.hints == 0:
            return  # the last frames of a pipeline being replaced (a reset): nothing was worked on
        if a.best < a.total:
            self._add_step(a, a.best + 1, "unfinished", now)

    # ------------------------------------------------------------------ writing
    def flush(self) -> bool:
        """Write what is buffered in one transaction; on a storage error keep it for the next try. True: written."""
        with self._lock:
            steps, totals = self._steps, self._totals
            self._steps, self._totals = [], {}
        if not steps and not totals:
            return True
        try:
            self.storage.record_results(steps, totals)
            return True
        except StorageError as exc:
            log.warning("learner results kept in memory until the database works again: %s", exc)
            with self._lock:  # put them back in front of what came meanwhile
                self._steps = steps + self._steps
                for sid, tot in totals.items():
                    cur = self._totals.setdefault(sid, {"wrong_placements": 0, "hints": 0})
                    cur["wrong_placements"] += tot.get("wrong_placements", 0)
                    cur["hints"] += tot.get("hints", 0)
                    for key in ("steps_total", "completed_at"):
                        if key in tot:
                            cur.setdefault(key, tot[key])
            return False

    def pending(self) -> int:
        """Step rows waiting to be written."""
        with self._lock:
            return len(self._steps)

    def start(self) -> None:
        """Flush every ``flush_interval_s`` seconds on a background thread until :meth:`stop`."""
        if self._thread is not None:
            return
        self._stop.clear()

        def loop() -> None:
            name_os_thread()
            while not self._stop.wait(self.flush_interval_s):
                self.flush()

        self._thread = threading.Thread(target=loop, name="results-writer", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """End the current session's record and write everything left (last try)."""
        self.switch(None, None)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        self.flush()


# ---------------------------------------------------------------------- the teacher's view
CSV_COLUMNS = ("session_id", "station", "mode", "task", "session_started", "session_ended", "completed",
               "attempt", "step", "label", "verdict", "step_started", "step_ended", "duration_s",
               "wrong_placements", "hints")


def task_name(session: dict[str, Any]) -> str:
    """The session's task reference; a mode's default task when none was named."""
    if session.get("task"):
        return str(session["task"])
    from tracker.pipeline import DEFAULT_TASKS

    return DEFAULT_TASKS.get(session.get("mode") or "", "(none)")


def _mean(values: list[float]) -> float | None:
    return round(sum(values) / len(values), 3) if values else None


def summarise(sessions: list[dict[str, Any]]) -> dict[str, Any]:
    """Per session, per step index, per task and per station: times (seconds) and error rates (0..1).

    The error rate of a step is the fraction of its attempts with at least one wrong placement."""
    out_sessions, by_step, groups = [], {}, {"task": {}, "station": {}}
    for s in sessions:
        steps = s.get("steps", [])
        done = [x for x in steps if x["verdict"] == "done"]
        row = {
            "id": s["id"], "station": s.get("station"), "mode": s.get("mode"), "task": task_name(s),
            "started_at": s["started_at"], "ended_at": s.get("ended_at"), "completed_at": s.get("completed_at"),
            "steps_total": s.get("steps_total"),
            "steps_done": max((sum(1 for x in done if x["attempt"] == k) for k in {x["attempt"] for x in done}),
                              default=0),  # of its best attempt
            "wrong_placements": s.get("wrong_placements", 0), "hints": s.get("hints", 0),
            "time_s": round(sum(x["duration_s"] for x in steps), 3),
        }
        out_sessions.append(row)
        for x in steps:
            by_step.setdefault(x["step"], []).append(x)
        for key in groups:
            groups[key].setdefault(row[key] or "(unnamed)", []).append((row, steps))
    step_rows = [
        {
            "step": k,
            "n": len(xs),
            "mean_time_s": _mean([x["duration_s"] for x in xs if x["verdict"] == "done"]),
            "error_rate": round(sum(1 for x in xs if x["wrong_placements"] > 0) / len(xs), 3),
            "hints": sum(x["hints"] for x in xs),
        }
        for k, xs in sorted(by_step.items())
    ]

    def group_rows(key: str) -> list[dict[str, Any]]:
        rows = []
        for name, members in sorted(groups[key].items()):
            steps = [x for _, xs in members for x in xs]
            rows.append({
                key: name,
                "sessions": len(members),
                "completed": sum(1 for r, _ in members if r["completed_at"] is not None),
                "mean_step_time_s": _mean([x["duration_s"] for x in steps if x["verdict"] == "done"]),
                "error_rate": round(sum(1 for x in steps if x["wrong_placements"] > 0) / len(steps), 3)
                if steps else None,
                "wrong_placements": sum(r["wrong_placements"] for r, _ in members),
                "hints": sum(r["hints"] for r, _ in members),
            })
        return rows

    return {"sessions": out_sessions, "steps": step_rows, "by_task": group_rows("task"),
            "by_station": group_rows("station")}


def _iso(t: float | None) -> str:
    return "" if t is None else time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t))


def _cell(value: Any) -> Any:
    """A CSV cell that a spreadsheet will not run as a formula (text starting with = + - @ gets a ')."""
    if isinstance(value, str) and value[:1] in ("=", "+", "-", "@", "\t", "\r"):
        return "'" + value
    return value


def csv_rows(sessions: list[dict[str, Any]]) -> list[list[Any]]:
    """One row per step (:data:`CSV_COLUMNS`); a session without steps gets one row with empty step fields."""
    rows = []
    for s in sessions:
        head = [s["id"], s.get("station") or "", s.get("mode") or "", task_name(s), _iso(s["started_at"]),
                _iso(s.get("ended_at")), "yes" if s.get("completed_at") is not None else "no"]
        steps = s.get("steps") or [None]
        for x in steps:
            tail = ["", "", "", "", "", "", "", "", ""] if x is None else [
                x["attempt"], x["step"], x["label"] or "", x["verdict"], _iso(x["started_at"]), _iso(x["ended_at"]),
                round(x["duration_s"], 3), x["wrong_placements"], x["hints"]]
            rows.append([_cell(v) for v in head + tail])
    return rows
