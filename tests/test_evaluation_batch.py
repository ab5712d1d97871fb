"""Batch evaluation: a real local Ray runtime (2 CPUs) and a process pool give the serial run's results."""

import json

import pytest
import ray

from app.cli import main

TINY = ["--sessions", "2", "--seeds", "100,101", "--poses", "groundtruth", "--frame-step", "3", "--max-time", "9"]
"""Two guess sessions (held-out seeds), ~90 frames each: the first has one connection by 9 s, the second two."""

TIMING = ("wall_seconds", "elapsed_seconds", "runner", "machine")


@pytest.fixture()
def local_ray():
    """A local Ray runtime of 2 CPUs; ``evaluate --ray`` uses a runtime that is already initialised as it is."""
    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=128 * 1024**2,
             logging_level="warning")
    try:
        yield
    finally:
        ray.shutdown()


def _run(out, extra: list[str]) -> tuple[dict, str, list[dict]]:
    assert main(["evaluate", "guess", "--out", str(out), *TINY, *extra]) == 0
    summary = json.loads((out / "summary.json").read_text())
    sessions = json.loads((out / "guess_sessions.json").read_text())
    for s in sessions:
        s.pop("seconds")
    return summary, (out / "guess.md").read_text(), sessions


def test_ray_and_process_pool_give_the_serial_results(tmp_path, capsys, local_ray):
    serial, serial_md, serial_sessions = _run(tmp_path / "serial", [])
    assert serial["runner"].startswith("serial") and serial["seeds"] == [100, 101]
    assert serial["sessions"] == 2 and serial["connections_total"] == 8
    assert serial["connections_detected"] == 3  # the run stops at 9 s: 1 + 2 connections made by then
    capsys.readouterr()

    on_ray, ray_md, ray_sessions = _run(tmp_path / "ray", ["--ray"])
    out = capsys.readouterr().out
    assert on_ray["runner"] == "Ray (local runtime, 2 CPUs)"
    assert "1/2 done" in out and "2/2 done" in out  # progress as sessions finish
    assert {k: v for k, v in on_ray.items() if k not in TIMING} == {k: v for k, v in serial.items() if k not in TIMING}
    assert ray_sessions == serial_sessions  # every detection time, guess history and final state, in order
    assert ray_md == serial_md

    pooled, pooled_md, pooled_sessions = _run(tmp_path / "pool", ["--jobs", "2"])
    assert pooled["runner"] == "process pool (2 processes)"
    assert pooled_sessions == serial_sessions and pooled_md == serial_md


def test_ray_and_jobs_are_exclusive(tmp_path, capsys):
    assert main(["evaluate", "guess", "--out", str(tmp_path), "--ray", "--jobs", "2"]) == 1
    assert "--ray or --jobs" in capsys.readouterr().err
