"""Scenario models, presets (TOML) and the simulator of truth and sensor returns."""

from .model import (
    BirthDeath,
    Dynamics,
    Grid,
    Looks,
    RayleighGridSensor,
    SuperpositionSensor,
    TrackingModel,
)
from .spec import Scenario, ScenarioError, get, load, preset_names

__all__ = [
    "BirthDeath", "Dynamics", "Grid", "Looks", "RayleighGridSensor", "Scenario",
    "ScenarioError", "SuperpositionSensor", "TrackingModel", "get", "load", "preset_names",
]
