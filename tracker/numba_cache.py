"""Where numba keeps the compiled kernels of this package, keyed by the kernels' source.

numba's on-disk cache (``@njit(cache=True)``) checks only the file of the function it loads: a kernel that calls a
kernel of another module keeps its compiled copy of the callee after the callee's source has changed (after a
``git pull`` or an upgrade, or an edit while developing), and runs the old code without a word. So the package puts
its cache in a directory named after a hash of the source of every module that defines kernels: any change to any
kernel gives a fresh directory (everything compiles once), and a cache built from other sources is never read.

The directory is ``<cache home>/assembly-agent/numba/<package path hash>/<source hash>`` (``$XDG_CACHE_HOME`` or
``~/.cache``); older source hashes of the same checkout are removed. ``NUMBA_CACHE_DIR`` set by the user wins.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
_MARKER = b"njit"


def source_hash(package: Path = _PACKAGE) -> str:
    """Hex digest of the path and content of every ``.py`` file under ``package`` that mentions ``njit``."""
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        data = path.read_bytes()
        if _MARKER in data:
            h.update(str(path.relative_to(package)).encode())
            h.update(b"\0")
            h.update(data)
    return h.hexdigest()[:16]


def cache_dir(package: Path = _PACKAGE) -> Path:
    """The numba cache directory for this checkout's kernel sources."""
    home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    checkout = hashlib.sha256(str(package).encode()).hexdigest()[:12]
    return home / "assembly-agent" / "numba" / checkout / source_hash(package)


def configure() -> Path | None:
    """Point numba's cache at :func:`cache_dir` unless ``NUMBA_CACHE_DIR`` is set; returns the directory used (None
    when the user's setting is kept or the directory cannot be made, when numba falls back to its own choice).
    Call before any kernel module is imported."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    target = cache_dir()
    try:
        target.mkdir(parents=True, exist_ok=True)
        for old in target.parent.iterdir():  # caches of this checkout's earlier kernel sources
            if old != target and old.is_dir():
                shutil.rmtree(old, ignore_errors=True)
    except OSError:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(target)
    numba = sys.modules.get("numba")
    if numba is not None:  # already imported (its config read the environment then): tell it too
        numba.config.CACHE_DIR = str(target)
    return target
