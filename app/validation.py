"""Checks at the edge of the API: task references, source names, recording folders, free text.

Everything a client sends is checked here (or in :mod:`app.api_models`) before it reaches the pipeline, the
storage or the file system: task references come from an allow-list (preset ids, ``teacher:<n>``), a recording
must lie inside one of the configured data folders, and text echoed back in an error message is clipped so a
huge input never ends up in a response or a log.
"""

from __future__ import annotations

import re
from pathlib import Path

MAX_TEACHER_TASK_ID = 2**31 - 1
"""Largest ``teacher:<n>`` id accepted (SQLite row ids of this server never get near it)."""
TEACHER_REF = re.compile(r"teacher:([0-9]{1,10})")
PRESET_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,79}")
CAMERA_ARG = re.compile(r"[0-9]{1,2}(,[0-9]{1,2})?")
CONTROL_CHARS = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def clip(text: object, n: int = 60) -> str:
    """``repr`` of ``text`` cut to about ``n`` characters (for error messages and logs)."""
    r = repr(text)
    return r if len(r) <= n else r[: n - 1] + "…"


def check_text(value: str, what: str = "text") -> str:
    """``value`` stripped; :class:`ValueError` if it is blank or holds NUL or other control characters."""
    if CONTROL_CHARS.search(value):
        raise ValueError(f"{what} contains control characters (such as NUL)")
    if not value.strip():
        raise ValueError(f"{what} is blank")
    return value.strip()


def teacher_task_id(ref: str) -> int | None:
    """The id of a ``teacher:<n>`` reference, ``None`` for another form; :class:`ValueError` for a bad number."""
    if not ref.startswith("teacher:"):
        return None
    match = TEACHER_REF.fullmatch(ref)
    if match is None or not 1 <= int(match.group(1)) <= MAX_TEACHER_TASK_ID:
        raise ValueError(f"task {clip(ref)}: expected teacher:<n> with 1 <= n <= {MAX_TEACHER_TASK_ID}")
    return int(match.group(1))


def check_preset_id(ref: str, known: list[str]) -> str:
    """``ref`` if it is one of the ``known`` preset ids, else a :class:`ValueError` listing them."""
    if PRESET_ID.fullmatch(ref) is None or ref not in known:
        raise ValueError(f"unknown task {clip(ref)}; choose one of {', '.join(known)} or teacher:<n>")
    return ref


def check_recording_dir(arg: str, roots: list[str]) -> Path:
    """The recording folder ``arg`` resolved, if it lies inside one of ``roots`` and exists (else ValueError).

    Symbolic links and ``..`` are resolved before the check, so no path leads outside the data folders."""
    path = Path(arg).expanduser().resolve()
    resolved_roots = [Path(r).expanduser().resolve() for r in roots]
    if not any(path == r or path.is_relative_to(r) for r in resolved_roots):
        allowed = ", ".join(str(r) for r in roots) or "none configured"
        raise ValueError(
            f"recording {clip(arg)}: recordings can only be opened from the data folders ({allowed}); "
            "add one with --recording-dir"
        )
    if not path.is_dir():
        raise ValueError(f"recording {clip(arg)}: no such recording folder")
    return path


def check_source_spec(spec: str, scenarios: list[str], recording_roots: list[str]) -> str:
    """``spec`` normalised if the API may open it: a known ``sim:`` scenario, ``camera:<n>[,<m>]`` or a
    ``recording:<dir>`` inside the data folders; :class:`ValueError` with the reason otherwise."""
    spec = check_text(spec, "source")
    kind, sep, arg = spec.partition(":")
    if not sep or kind not in ("sim", "recording", "camera"):
        raise ValueError(f"source {clip(spec)}: expected sim:<scenario>, recording:<dir> or camera:<n>")
    if kind == "sim":
        if arg not in scenarios:
            raise ValueError(f"source {clip(spec)}: unknown scenario; scenarios: {', '.join(scenarios)}")
    elif kind == "camera":
        if CAMERA_ARG.fullmatch(arg) is None:
            raise ValueError(f"source {clip(spec)}: expected camera:<n> or camera:<colour>,<depth> (device numbers)")
    else:
        check_recording_dir(arg, recording_roots)
    return spec
