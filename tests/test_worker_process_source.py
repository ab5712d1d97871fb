"""The simulator rendered in a child process gives the same frames as in-process; failures are SourceErrors."""

from __future__ import annotations

import functools
import os

import numpy as np
import pytest

from app.source_process import ProcessSource, SharedView
from app.worker import PipelineWorker, _RandomAccess
from tracker.sources.base import SourceError
from tracker.sources.simulator import SimOptions, SimulatedTable

OPTIONS = SimOptions(width=160, height=120, focal=131.25)
make_sim = functools.partial(SimulatedTable, "static", seed=5, options=OPTIONS, n_frames=40)


@pytest.fixture(scope="module")
def proc():
    src = ProcessSource(make_sim)
    yield src
    src.close()


def test_child_frames_equal_in_process_frames(proc):
    ref = make_sim()
    assert proc.n_frames == 40 and len(proc) == 40
    assert proc.intrinsics.to_dict() == ref.intrinsics.to_dict()
    assert [p.name for p in proc.parts] == [p.name for p in ref.parts]
    assert set(proc.initial_poses) == set(ref.initial_poses)
    assert proc.metadata()["fps"] == 30.0
    for i in (0, 7, 3):  # random access, out of order
        a, b = proc.render(i), ref.render(i)
        assert a.index == b.index == i and a.timestamp == b.timestamp
        assert np.array_equal(a.color, b.color)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        assert set(a.meta["groundtruth"]["poses"]) == set(ref.initial_poses)
    # frames are copies: a later render does not change an earlier frame
    f0 = proc.render(0)
    before = f0.color.copy()
    proc.render(20)
    assert np.array_equal(f0.color, before)


def test_bad_index_is_a_source_error_and_the_process_goes_on(proc):
    with pytest.raises(SourceError, match="frame -1"):
        proc.render(-1)
    assert proc.render(1).index == 1


def test_shared_view_is_paced_by_the_worker_and_keeps_the_process(proc):
    view = SharedView(proc)
    acc = _RandomAccess.of(view)
    assert acc is not None and acc.count == 40 and acc.fps == 30.0
    view.close()
    assert proc.alive  # closing the view leaves the process running
    seen = []
    from test_worker import make_pipeline

    worker = PipelineWorker(lambda: SharedView(proc), make_pipeline, max_fps=None, loop=False, realtime=False)
    worker.add_listener(lambda s: seen.append(s.frame_index))
    worker.start()
    try:
        from test_worker import wait_for

        assert wait_for(lambda: worker.state == "finished", timeout=60)
    finally:
        worker.stop()
    assert seen == list(range(40))


def test_failing_factory_and_closed_source():
    with pytest.raises(SourceError, match="unknown scenario|no-such"):
        ProcessSource(functools.partial(SimulatedTable, "no-such-scenario"))
    src = ProcessSource(make_sim)
    src.close()
    assert not src.alive
    with pytest.raises(SourceError, match="closed"):
        src.render(0)


def test_the_source_process_is_named_for_the_os(proc):
    comm = f"/proc/{proc._proc.pid}/comm"
    if not os.path.exists("/proc/thread-self/comm"):
        pytest.skip("no /proc/thread-self (not Linux)")
    with open(comm) as f:
        assert f.read().strip() == "frame-source"
