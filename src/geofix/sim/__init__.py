"""Simulation: validated scenarios and the missions (trials) simulated from them."""

from geofix.sim.scenario import (
    DvlSpec,
    FieldSpec,
    InsSpec,
    MapSpec,
    Scenario,
    SeabedSpec,
    SensorSpec,
    TrackSpec,
    load_scenario,
    scenario_from_dict,
)
from geofix.sim.simulate import (
    check_track_on_map,
    prepare_field_maps,
    prepare_map,
    simulate_trial,
    simulate_trials,
    start_position,
)
from geofix.sim.trial import Trial, TrialField

__all__ = [
    "DvlSpec",
    "FieldSpec",
    "InsSpec",
    "MapSpec",
    "Scenario",
    "SeabedSpec",
    "SensorSpec",
    "TrackSpec",
    "Trial",
    "TrialField",
    "check_track_on_map",
    "load_scenario",
    "prepare_field_maps",
    "prepare_map",
    "scenario_from_dict",
    "simulate_trial",
    "simulate_trials",
    "start_position",
]
