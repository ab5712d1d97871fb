"""Threads name themselves for the OS (top -H, ps -L, bench_server's CPU per thread)."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from tracker.os_names import name_os_thread

pytestmark = pytest.mark.skipif(not Path("/proc/thread-self/comm").exists(), reason="no /proc/thread-self")


def _os_name_in_thread(name: str | None, py_name: str) -> str:
    got: list[str] = []

    def run() -> None:
        name_os_thread(name)
        got.append(Path("/proc/thread-self/comm").read_text().strip())

    t = threading.Thread(target=run, name=py_name)
    t.start()
    t.join()
    return got[0]


def test_a_thread_takes_its_python_name_cut_to_15_bytes():
    assert _os_name_in_thread(None, "pipeline-worker") == "pipeline-worker"
    assert _os_name_in_thread(None, "a-much-longer-thread-name") == "a-much-longer-t"


def test_an_explicit_name_wins_and_the_calling_thread_only_is_renamed():
    main_before = Path("/proc/thread-self/comm").read_text()
    assert _os_name_in_thread("frame-source", "x") == "frame-source"
    assert Path("/proc/thread-self/comm").read_text() == main_before
