"""2D observations of 3D joints: synthetic corruption scenarios and their npz storage."""

from priortrack.observation.synthetic import (
    FORMAT_VERSION,
    PAPER_OBSERVED,
    SCENARIOS,
    Observations,
    ScenarioSpec,
    default_camera,
    parse_scenario,
    synthesize,
)

__all__ = [
    "FORMAT_VERSION",
    "PAPER_OBSERVED",
    "SCENARIOS",
    "Observations",
    "ScenarioSpec",
    "default_camera",
    "parse_scenario",
    "synthesize",
]
