"""Names of threads and child processes as the operating system shows them (``top -H``, ``ps -L``, /proc).

Python's thread names live only inside Python; on Linux, writing ``/proc/thread-self/comm`` gives the calling
thread an OS name as well (at most 15 bytes), and a child process's main thread names the process. The
benchmarks read these names to report CPU time per thread and per process (``benchmarks/bench_server.py``).
"""

from __future__ import annotations

import threading
from pathlib import Path

_COMM = Path("/proc/thread-self/comm")


def name_os_thread(name: str | None = None) -> None:
    """Give the calling thread the OS name ``name`` (default: its Python name), cut to 15 bytes; on systems
    without ``/proc/thread-self`` (or if writing fails) nothing happens."""
    text = (name if name is not None else threading.current_thread().name).encode()[:15]
    try:
        _COMM.write_bytes(text)
    except OSError:
        pass
