"""The simulated RGB-D table: ``SimulatedTable(scenario, seed, options, realtime, n_frames)``.

Modules: :mod:`.scene` (camera placement, table, light), :mod:`.rasterizer` (numba ray casting),
:mod:`.sensor_model` (depth and colour noise), :mod:`.hand` (hand geometry), :mod:`.scenarios`
(structures and scripts), :mod:`.source` (the FrameSource).
"""

from tracker.sources.simulator.scenarios import (
    SCENARIOS,
    ConnectionEvent,
    ScenarioInfo,
    Structure,
    face_adjacent,
    get_scenario,
    list_scenarios,
)
from tracker.sources.simulator.sensor_model import ColorSensorModel, DepthSensorModel
from tracker.sources.simulator.source import FPS, SimOptions, SimulatedTable

__all__ = [
    "FPS",
    "SCENARIOS",
    "ColorSensorModel",
    "ConnectionEvent",
    "DepthSensorModel",
    "ScenarioInfo",
    "SimOptions",
    "SimulatedTable",
    "Structure",
    "face_adjacent",
    "get_scenario",
    "list_scenarios",
]
