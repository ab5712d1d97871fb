"""Running a batch of evaluation sessions: one by one, in a local process pool, or spread over a Ray cluster.

Every runner takes the same list of :class:`SessionJob` (a session and the keyword arguments of
:func:`tracker.evaluation.runner.run_session`) and returns their results **in the order of the list**, whatever
order they finish in. Each session is seeded by its own spec (simulator, noise, tracker), so a session's result
does not depend on where or after which other session it runs: the merged results, and every summary computed
from them, equal the serial run's. ``on_done(k, result, n_done)`` is called in the calling process as each session
finishes (progress display); only the serial runner also reports frames within a session (``on_frame``).

* :class:`SerialRunner`: in this process, in order (the reference).
* :class:`ProcessPoolRunner`: ``jobs`` worker processes on this machine (``evaluate --jobs N``).
* :class:`RayRunner`: Ray tasks of one CPU each (``evaluate --ray [ADDRESS]``): a local Ray runtime using this
  machine's cores by default, or an existing cluster (``auto`` = the one ``ray start`` runs on this machine,
  ``HOST:PORT`` or ``ray://HOST:PORT``). Every node of a cluster needs this package installed (the same commit);
  a cluster with token authentication is joined with ``RAY_AUTH_MODE=token`` and its token in the environment.
  Ray is an optional dependency: ``pip install -e ".[ray]"``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Protocol

from tracker.evaluation.runner import SessionResult, run_session
from tracker.evaluation.sessions import SessionSpec

OnDone = Callable[[int, SessionResult, int], None]
"""``on_done(k, result, n_done)``: job ``k`` finished with ``result``; ``n_done`` jobs are finished so far."""


@dataclass(frozen=True)
class SessionJob:
    """One session to run: ``run_session(spec, **kwargs)`` (kwargs must pickle; no callbacks)."""

    spec: SessionSpec
    kwargs: dict = field(default_factory=dict)

    def run(self, on_frame: Callable[[int, int], None] | None = None) -> SessionResult:
        return run_session(self.spec, **self.kwargs, on_frame=on_frame)


def _run_job(job: SessionJob) -> SessionResult:
    """Module-level (picklable) entry point of a worker process."""
    return job.run()


def usable_cores() -> int:
    """Cores this process may run on (the affinity mask; ``os.cpu_count()`` where that is unknown)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


class BatchRunner(Protocol):
    """Runs session jobs and returns their results in job order."""

    name: str
    frame_progress: bool
    """True when ``on_frame`` is called during sessions (else progress comes per finished session only)."""

    def describe(self) -> str: ...

    def run(self, jobs: Sequence[SessionJob], on_done: OnDone | None = None,
            on_frame: Callable[[int, int], None] | None = None) -> list[SessionResult]: ...


class SerialRunner:
    """The sessions one after the other in this process (the reference for the others)."""

    name = "serial"
    frame_progress = True

    def describe(self) -> str:
        return "serial (1 process)"

    def run(self, jobs: Sequence[SessionJob], on_done: OnDone | None = None,
            on_frame: Callable[[int, int], None] | None = None) -> list[SessionResult]:
        results = []
        for k, job in enumerate(jobs):
            results.append(job.run(on_frame))
            if on_done:
                on_done(k, results[-1], k + 1)
        return results


class ProcessPoolRunner:
    """``workers`` spawned processes on this machine, one session each at a time."""

    name = "processes"
    frame_progress = False

    def __init__(self, workers: int):
        if workers < 1:
            raise ValueError("--jobs must be at least 1")
        self.workers = workers

    def describe(self) -> str:
        return f"process pool ({self.workers} processes)"

    def run(self, jobs: Sequence[SessionJob], on_done: OnDone | None = None,
            on_frame: Callable[[int, int], None] | None = None) -> list[SessionResult]:
        results: list[SessionResult | None] = [None] * len(jobs)
        with ProcessPoolExecutor(max_workers=min(self.workers, max(1, len(jobs))),
                                 mp_context=get_context("spawn")) as pool:
            pending = {pool.submit(_run_job, job): k for k, job in enumerate(jobs)}
            n_done = 0
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in sorted(finished, key=pending.get):
                    k = pending.pop(fut)
                    results[k] = fut.result()
                    n_done += 1
                    if on_done:
                        on_done(k, results[k], n_done)
        return results  # type: ignore[return-value]


class RayRunner:
    """Ray tasks (one CPU each) on a local Ray runtime or an existing cluster.

    ``address=None``: start a local runtime with ``num_cpus`` CPUs (default: this machine's usable cores) and stop
    it afterwards; otherwise join the cluster at ``address`` (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``) and
    leave it running. A Ray runtime that is already initialised in this process is used as it is."""

    name = "ray"
    frame_progress = False

    def __init__(self, address: str | None = None, num_cpus: int | None = None):
        try:
            import ray  # noqa: F401
        except ImportError:
            raise RuntimeError('--ray needs Ray, an optional dependency: pip install -e ".[ray]"') from None
        if num_cpus is not None and num_cpus < 1:
            raise ValueError("num_cpus must be at least 1")
        if address is not None and num_cpus is not None:
            raise ValueError("num_cpus is for a local Ray runtime; a cluster has its own")
        self.address = address
        self.num_cpus = num_cpus
        self.cluster_cpus: float | None = None

    def describe(self) -> str:
        where = f"cluster at {self.address}" if self.address else "local runtime"
        cpus = f", {self.cluster_cpus:g} CPUs" if self.cluster_cpus else ""
        return f"Ray ({where}{cpus})"

    def _start(self) -> bool:
        """Initialise Ray unless it already is; True when this call did (and so must shut it down)."""
        import ray

        if ray.is_initialized():
            return False
        common = {"include_dashboard": False, "log_to_driver": True, "configure_logging": True,
                  "logging_level": "warning"}
        try:
            if self.address is None:
                # A small object store: results are a few kB each (Ray's default takes 30 % of the memory).
                ray.init(address="local", num_cpus=self.num_cpus or usable_cores(),
                         object_store_memory=128 * 1024**2, **common)
            else:
                ray.init(address=self.address, **common)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            where = f"the Ray cluster at {self.address}" if self.address else "a local Ray runtime"
            hint = ("" if self.address is None or os.environ.get("RAY_AUTH_MODE") else
                    " (a cluster that uses token authentication, which `ray start` does by default since Ray 2.59, "
                    "is joined with RAY_AUTH_MODE=token and its token, ~/.ray/auth_token or RAY_AUTH_TOKEN)")
            raise RuntimeError(f"could not start or join {where}: {exc}{hint}") from exc
        return True

    def run(self, jobs: Sequence[SessionJob], on_done: OnDone | None = None,
            on_frame: Callable[[int, int], None] | None = None) -> list[SessionResult]:
        import ray

        started = self._start()
        try:
            self.cluster_cpus = float(ray.cluster_resources().get("CPU", 0.0))
            task = ray.remote(num_cpus=1, max_retries=0)(_run_job)
            refs = [task.remote(job) for job in jobs]
            index = {ref: k for k, ref in enumerate(refs)}
            results: list[SessionResult | None] = [None] * len(jobs)
            pending, n_done = list(refs), 0
            while pending:
                finished, pending = ray.wait(pending, num_returns=1)
                for ref in finished:
                    k = index[ref]
                    try:
                        results[k] = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:
                        raise RuntimeError(f"session {jobs[k].spec.index + 1} (seed {jobs[k].spec.seed}) failed "
                                           f"on a Ray worker: {exc.cause!r}") from exc
                    n_done += 1
                    if on_done:
                        on_done(k, results[k], n_done)
            return results  # type: ignore[return-value]
        finally:
            if started:
                ray.shutdown()


def make_runner(ray: str | None = None, jobs: int = 1) -> BatchRunner:
    """The runner for ``evaluate``'s options: ``ray`` = ``"local"`` (a local runtime) or a cluster address;
    else ``jobs`` > 1 = a process pool; else serial."""
    if ray is not None:
        if jobs != 1:
            raise ValueError("give --ray or --jobs, not both")
        return RayRunner(address=None if ray == "local" else ray)
    if jobs < 1:
        raise ValueError("--jobs must be at least 1")
    return SerialRunner() if jobs == 1 else ProcessPoolRunner(jobs)


def timed(runner: BatchRunner, jobs: Sequence[SessionJob], on_done: OnDone | None = None,
          on_frame: Callable[[int, int], None] | None = None) -> tuple[list[SessionResult], float]:
    """``runner.run(...)`` and its wall time in seconds (start-up of workers or of a Ray runtime included)."""
    t0 = time.perf_counter()
    results = runner.run(jobs, on_done=on_done, on_frame=on_frame)
    return results, time.perf_counter() - t0
