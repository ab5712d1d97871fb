"""Open any frame source by name: ``open_source("sim:guess-2" | "recording:DIR" | "camera:0[,2]", **options)``.

The same source names are used by every command, the web app and the tests:

* ``sim:<scenario>``: the simulated table (:class:`tracker.sources.simulator.SimulatedTable`); options ``seed``,
  ``realtime``, ``speed``, ``occlusion``, ``excursions``, ``n_frames``, ``camera_motion`` (``none``, ``sway``,
  ``handheld``).
* ``recording:<dir>`` (or just ``<dir>``, an existing directory): a recording on disk
  (:class:`tracker.sources.recording.RecordingSource`); options ``loop``, ``realtime``, ``prefetch``.
* ``camera:<colour>[,<depth>]``: live capture through OpenCV (:class:`tracker.sources.camera.CameraSource`);
  options ``calibration`` (path of the calibration JSON), ``fps``, ``pair_tolerance``, ``read_timeout``.

Options that belong to another kind of source are ignored (so one options dict can serve every source);
unknown option names and unknown schemes raise :class:`ValueError`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tracker.sources.base import FrameSource

SOURCE_FORMS = (
    "sim:<scenario> (simulated table, e.g. sim:guess-2)",
    "recording:<dir> (or a recording directory path)",
    "camera:<colour>[,<depth>] (OpenCV devices, e.g. camera:4,2 with a calibration file)",
)
"""The valid source names, for help texts and error messages."""

SOURCE_HELP = "frame source: " + "; ".join(SOURCE_FORMS)

SIM_OPTIONS = ("seed", "realtime", "speed", "occlusion", "excursions", "n_frames", "camera_motion")
RECORDING_OPTIONS = ("loop", "realtime", "prefetch")
CAMERA_OPTIONS = ("calibration", "fps", "pair_tolerance", "read_timeout", "retry_delay", "max_retry_delay")
_ALL_OPTIONS = set(SIM_OPTIONS) | set(RECORDING_OPTIONS) | set(CAMERA_OPTIONS)


def parse_source_spec(spec: str) -> tuple[str, str]:
    """``(kind, argument)`` with kind ``"sim"``, ``"recording"`` or ``"camera"``; :class:`ValueError` otherwise."""
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"empty source; valid forms: {'; '.join(SOURCE_FORMS)}")
    spec = spec.strip()
    scheme, sep, rest = spec.partition(":")
    if sep and scheme in ("sim", "recording", "camera"):
        if not rest.strip():
            raise ValueError(f"source {spec!r} lacks its argument; valid forms: {'; '.join(SOURCE_FORMS)}")
        return scheme, rest.strip()
    if Path(spec).is_dir():
        return "recording", spec
    if sep and len(scheme) > 1 and "/" not in scheme:
        raise ValueError(f"unknown source scheme {scheme + ':'!r} in {spec!r}; valid forms: {'; '.join(SOURCE_FORMS)}")
    raise ValueError(f"source {spec!r} is neither a known scheme nor an existing recording directory; "
                     f"valid forms: {'; '.join(SOURCE_FORMS)}")


def open_source(spec: str, **options: Any) -> FrameSource:
    """Open the frame source named by ``spec`` (see the module docstring); ``None`` options mean default."""
    unknown = sorted(set(options) - _ALL_OPTIONS)
    if unknown:
        raise ValueError(f"unknown source option(s) {', '.join(unknown)}; known: {', '.join(sorted(_ALL_OPTIONS))}")
    kind, arg = parse_source_spec(spec)
    given = {k: v for k, v in options.items() if v is not None}
    if kind == "sim":
        return _open_sim(arg, given)
    if kind == "recording":
        from tracker.sources.recording import RecordingSource

        return RecordingSource(Path(arg).expanduser(), **{k: v for k, v in given.items() if k in RECORDING_OPTIONS})
    from tracker.sources.camera import CameraSource

    return CameraSource(arg, **{k: v for k, v in given.items() if k in CAMERA_OPTIONS})


def _open_sim(scenario: str, given: dict[str, Any]) -> FrameSource:
    from tracker.sources.simulator import SimOptions, SimulatedTable, list_scenarios

    names = _scenario_names(list_scenarios())
    if names and scenario not in names:
        raise ValueError(f"unknown scenario {scenario!r} in sim:{scenario}; scenarios: {', '.join(names)}")
    sim_opts = {k: given[k] for k in ("speed", "occlusion", "excursions", "camera_motion") if k in given}
    return SimulatedTable(
        scenario,
        seed=int(given.get("seed", 0)),
        options=SimOptions(**sim_opts),
        realtime=bool(given.get("realtime", False)),
        n_frames=given.get("n_frames"),
    )


def _scenario_names(listed: Any) -> list[str]:
    """Names from whatever ``list_scenarios()`` returns (names, objects with ``.name``, or a name→x mapping)."""
    if isinstance(listed, dict):
        return [str(k) for k in listed]
    out = []
    for item in listed or ():
        out.append(item if isinstance(item, str) else str(getattr(item, "name", item)))
    return out
