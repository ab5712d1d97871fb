"""bench_server's scheduler states and frame steps (they tell a starved pipeline from a blocked one)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_server import (  # noqa: E402
    cached_kernels,
    cpu_seconds,
    cpu_split,
    frame_steps,
    machine_split,
    machine_ticks,
    replaced_children,
    sched_by_thread,
    sched_split,
)


def test_sched_split_shares_of_the_wall_time():
    before = {11: ("server/pipeline-worker", 1.0, 0.5), 12: ("hands/main", 0.0, 0.0), 13: ("server/other", 0.0, 0.0),
              14: ("server/other", 2.0, 0.0)}  # fmt: skip
    after = {11: ("server/pipeline-worker", 5.0, 3.5), 12: ("hands/main", 1.0, 2.0), 13: ("server/other", 1.0, 0.0),
             14: ("server/other", 3.0, 1.0), 15: ("server/other", 9.0, 0.0)}  # fmt: skip
    got = sched_split(before, after, 10.0)
    assert got["server/pipeline-worker"] == {"run": 40.0, "runqueue": 30.0, "blocked": 30.0}
    assert got["hands/main"] == {"run": 10.0, "runqueue": 20.0, "blocked": 70.0}
    # two threads of one key share 20 s of wall time; the thread started between the readings (15) is left out
    assert got["server/other"] == {"run": 10.0, "runqueue": 5.0, "blocked": 85.0}


def test_sched_split_leaves_out_a_reused_thread_id():
    got = sched_split({7: ("server/frame-reader", 1.0, 1.0)}, {7: ("hands/main", 2.0, 1.0)}, 1.0)
    assert got == {}


def test_frame_steps():
    assert frame_steps([10, 11, 12, 13]) == {"mean": 1.0, "max": 1}
    assert frame_steps([10, 12, 15, 0, 3]) == {"mean": 2.67, "max": 3}  # 15 -> 0: the source looped
    assert frame_steps([5]) is None


@pytest.mark.skipif(not Path(f"/proc/{os.getpid()}/task").exists(), reason="no /proc")
def test_sched_by_thread_reads_this_process_threads():
    stop = threading.Event()
    t = threading.Thread(target=stop.wait, name="idle")
    t.start()
    try:
        s0 = sched_by_thread(os.getpid())
        s1 = sched_by_thread(os.getpid())
    finally:
        stop.set()
        t.join()
    if t.native_id not in s0:
        pytest.skip("no schedstat in this kernel")
    assert t.native_id in s1 and threading.get_native_id() in s1
    key, run, wait = s1[t.native_id]
    assert key.startswith("server/") and run >= s0[t.native_id][1] >= 0.0 and wait >= s0[t.native_id][2] >= 0.0


@pytest.mark.skipif(not Path(f"/proc/{os.getpid()}/stat").exists(), reason="no /proc")
def test_cpu_seconds_keeps_the_cpu_of_a_child_that_ended():
    """A child that burns CPU and ends between two readings (session 20: the server's hand process, ended and replaced
    mid-run, gave negative CPU per frame) keeps its CPU time in the sum: the second reading exceeds the first by at
    least the child's CPU, though the child is gone."""
    before = cpu_seconds(os.getpid())
    child = subprocess.run([sys.executable, "-c", "import time\nt = time.process_time()\n"
                            "while time.process_time() - t < 0.5: pass"], check=True)  # fmt: skip
    assert child.returncode == 0
    assert cpu_seconds(os.getpid()) - before >= 0.45


def test_cpu_split_and_replaced_children():
    before = {"server/pipeline-worker": 1.0, "hands/main": 3.0, "ended/children": 0.0}
    after = {"server/pipeline-worker": 2.0, "hands/main": 0.5, "ended/children": 4.0}  # a new hand process
    by_process, by_thread = cpu_split(before, after, 10)
    assert by_thread["ended/children"] == 400.0 and by_process["server"] == 100.0
    assert replaced_children({11: "simulator", 12: "hands"}, {11: "simulator", 13: "hands"}) == ["hands"]
    assert replaced_children({11: "simulator"}, {11: "simulator", 13: "hands"}) == []


def test_cached_kernels_counts_numba_cache_files(tmp_path):
    """A kernel compiled with ``cache=True`` while the run is measured writes its index and object files: the count
    grows (the benchmark then reports the run as not steady)."""
    assert cached_kernels(tmp_path) == 0
    sub = tmp_path / "a" / "b"
    sub.mkdir(parents=True)
    (sub / "mod.kernel-12.py311.nbi").write_bytes(b"")
    (sub / "mod.kernel-12.py311.1.nbc").write_bytes(b"")
    (sub / "notes.txt").write_text("x")
    assert cached_kernels(tmp_path) == 2


def test_machine_ticks_and_split(tmp_path):
    """The machine's busy, idle and stolen ticks from a /proc/stat ``cpu`` line, and their split over a run: busy
    time beyond the server's own CPU is other jobs', steal the host's (in % of one core)."""
    stat = tmp_path / "stat"
    stat.write_text("cpu  100 5 20 400 10 1 2 30 0 0\ncpu0 50 2 10 200 5 0 1 15 0 0\n")
    before = machine_ticks(stat)
    assert before == {"busy": 128, "idle": 410, "steal": 30}
    tick = os.sysconf("SC_CLK_TCK")
    after = {"busy": 128 + 3 * tick, "idle": 410, "steal": 30 + tick // 2}  # 3 s busy, 0.5 s stolen in 2 s
    got = machine_split(before, after, server_cpu_s=2.0, wall_s=2.0)
    assert got == {"busy": 150.0, "other_jobs": 50.0, "steal": 25.0}
    assert machine_split(before, None, 2.0, 2.0) is None
    (tmp_path / "bad").write_text("intr 1 2 3\n")
    assert machine_ticks(tmp_path / "bad") is None and machine_ticks(tmp_path / "missing") is None
    if Path("/proc/stat").exists():
        now = machine_ticks()
        assert now is not None and now["busy"] > 0
