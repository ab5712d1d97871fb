"""The numba cache directory is keyed by the kernels' source (tracker/numba_cache.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from tracker import numba_cache


def _package(root: Path) -> Path:
    pkg = root / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "kernels.py").write_text("import numba as nb\n\n@nb.njit(cache=True)\ndef f(x):\n    return x + 1\n")
    (pkg / "sub" / "caller.py").write_text("@nb.njit(cache=True)\ndef g(x):\n    return f(x)\n")
    (pkg / "plain.py").write_text("def h():\n    return 1\n")
    return pkg


def test_the_source_hash_changes_with_any_kernel_module_and_only_with_them(tmp_path):
    pkg = _package(tmp_path)
    first = numba_cache.source_hash(pkg)
    assert numba_cache.source_hash(pkg) == first
    (pkg / "plain.py").write_text("def h():\n    return 2\n")  # no kernel in it: same cache
    assert numba_cache.source_hash(pkg) == first
    (pkg / "kernels.py").write_text((pkg / "kernels.py").read_text().replace("x + 1", "x + 2"))  # a callee changed
    second = numba_cache.source_hash(pkg)
    assert second != first
    (pkg / "sub" / "caller.py").rename(pkg / "sub" / "caller2.py")  # a kernel module renamed
    assert numba_cache.source_hash(pkg) not in (first, second)


def test_the_package_sets_numba_cache_dir_unless_the_user_did(tmp_path):
    code = "import tracker, os, numba; print(os.environ['NUMBA_CACHE_DIR']); print(numba.config.CACHE_DIR)"
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache")}
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    lines = out.split()
    assert lines[0] == lines[1]
    used = Path(lines[0])
    assert used.is_dir() and used.parent.parent == tmp_path / "cache" / "assembly-agent" / "numba"
    assert used.name == numba_cache.source_hash()
    # an older source hash of the same checkout is removed; the user's own setting wins
    stale = used.parent / "0123456789abcdef"
    stale.mkdir()
    subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert not stale.exists() and used.is_dir()
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == [str(tmp_path / "mine")] * 2
