"""The lock files agree with pyproject.toml: every dependency pinned, at a version it allows, with hashes.

A dependency added to pyproject.toml without ``bash scripts/update-lock.sh`` fails here with its name.
"""

import re
import tomllib
from pathlib import Path

import pytest
from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
LOCKS = {
    "requirements.lock": ("test", "ray"),  # setup.sh and CI
    "requirements-app.lock": (),  # the Docker image
    "requirements-bench.lock": ("test", "ray", "bench"),
}
"""Each lock file and the extras of pyproject.toml it covers."""
PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)\s*(?:;\s*([^\\]+?))?\s*\\?$")


def _pins(text: str) -> dict[str, list[tuple[str, str | None, int]]]:
    """name → [(version, marker, number of hashes)] (a universal lock may pin a name once per marker)."""
    pins: dict[str, list[tuple[str, str | None, int]]] = {}
    current = None
    for line in text.splitlines():
        m = PIN.match(line)
        if m:
            current = [m.group(2), m.group(3), 0]
            pins.setdefault(canonicalize_name(m.group(1)), []).append(current)
        elif current is not None and line.strip().startswith("--hash=sha256:"):
            current[2] += 1
    return {k: [tuple(v) for v in vs] for k, vs in pins.items()}


def _wanted(extras: tuple[str, ...]) -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    reqs = [Requirement(r) for r in project["dependencies"]]
    for extra in extras:
        reqs += [Requirement(r) for r in project["optional-dependencies"][extra]]
    return reqs


@pytest.mark.parametrize("lock", sorted(LOCKS))
def test_lock_pins_every_dependency_with_hashes(lock):
    text = (ROOT / lock).read_text()
    pins = _pins(text)
    assert pins, f"{lock} pins nothing"
    env = default_environment()  # this machine (Linux, the Python running the tests)
    for req in _wanted(LOCKS[lock]):
        name = canonicalize_name(req.name)
        assert name in pins, f"{req.name} is in pyproject.toml but not in {lock}: run bash scripts/update-lock.sh"
        here = [v for v, marker, _ in pins[name] if marker is None or Requirement(f"x; {marker}").marker.evaluate(env)]
        assert here, f"{lock} pins {req.name} for no environment like this one"
        assert all(req.specifier.contains(v, prereleases=True) for v in here), \
            f"{lock} pins {req.name}=={here} outside pyproject.toml's {req.specifier}: run bash scripts/update-lock.sh"
    assert all(n_hashes >= 1 for vs in pins.values() for _, _, n_hashes in vs), f"a pin of {lock} has no hash"
    assert not re.search(r"--(extra-)?index-url|--find-links|://", text), f"{lock} names an index or a URL"


def test_bench_lock_keeps_the_main_versions():
    main, bench = _pins((ROOT / "requirements.lock").read_text()), _pins((ROOT / "requirements-bench.lock").read_text())
    assert "open3d" in bench and "open3d" not in main
    differ = {n: (main[n], bench[n]) for n in main if n in bench and
              sorted(v for v, *_ in main[n]) != sorted(v for v, *_ in bench[n])}
    assert not differ, f"requirements-bench.lock moves versions of requirements.lock: {differ}"
