"""geofix: keep an underwater vehicle's position true without GPS.

Terrain- and gravity-aided navigation: match what the vehicle measures (echosounder
depths, gravimeter anomalies) against a prior map to correct INS drift. See
:mod:`geofix.conventions` for frames, angles and units.

The names below are the public API, importable from ``geofix`` itself; each is loaded
on first use, so ``import geofix`` stays quick.

Examples
--------
>>> import geofix
>>> scen = geofix.load_scenario("builtin:azores_demo")
>>> grid = geofix.prepare_map(scen)
>>> trial = geofix.simulate_trial(scen, grid, 0)
>>> trial.truth.shape
(80, 2)
"""

from __future__ import annotations

from geofix import _lifetime

_lifetime.arm_in_spawned_worker()  # first: a worker starting up dies with its parent

import importlib  # noqa: E402

from geofix._version import __version__ as __version__  # noqa: E402

#: Public name -> module that defines it.
_PUBLIC = {
    # maps
    "Grid": "geofix.maps.grid",
    "load_map": "geofix.maps.io",
    "save_map": "geofix.maps.io",
    "bundled_maps": "geofix.maps.bundled",
    # problem values and the measurement model
    "MatchProblem": "geofix.problem",
    "Fix": "geofix.problem",
    "Matcher": "geofix.problem",
    # scenarios and simulation
    "Scenario": "geofix.sim.scenario",
    "load_scenario": "geofix.sim.scenario",
    "scenario_from_dict": "geofix.sim.scenario",
    "prepare_map": "geofix.sim.simulate",
    "simulate_trial": "geofix.sim.simulate",
    "simulate_trials": "geofix.sim.simulate",
    "Trial": "geofix.sim.trial",
    "export_trials": "geofix.sim.export",
    "load_exported": "geofix.sim.export",
    # methods
    "Tercom": "geofix.match.tercom",
    "Iccp": "geofix.match.iccp",
    "MultipathIccp": "geofix.match.iccp",
    "GaSca": "geofix.match.ga_sca",
    "Icp": "geofix.match.icp",
    "TercomIcp": "geofix.match.icp",
    "AbcMhd": "geofix.match.abc",
    "Ioap": "geofix.match.ioap",
    "Sitan": "geofix.filters.sitan",
    "SitanBank": "geofix.filters.sitan",
    "Pmf": "geofix.filters.pmf",
    "Pf": "geofix.filters.pf",
    "Mpf": "geofix.filters.mpf",
    "FreeIns": "geofix.match.free_ins",
    "available_methods": "geofix.methods",
    "parse_method_spec": "geofix.methods",
    "register": "geofix.methods",
    # evaluation
    "run_trial": "geofix.evaluate.runner",
    "TrialResult": "geofix.evaluate.runner",
    "run_campaign": "geofix.evaluate.campaign",
    "CampaignResult": "geofix.evaluate.campaign",
    "CampaignSummary": "geofix.evaluate.summary",
    "MethodStats": "geofix.evaluate.summary",
    "suitability": "geofix.evaluate.suitability",
    # errors
    "GeofixError": "geofix.errors",
    "ConfigError": "geofix.errors",
    "MapError": "geofix.errors",
    "MatchError": "geofix.errors",
    "TrackOffMapError": "geofix.errors",
    "InputError": "geofix.errors",
    # recorded missions and the online navigator
    "Mission": "geofix.logs.mission",
    "read_mission": "geofix.logs.read",
    "Navigator": "geofix.navigator",
}

#: Public names whose defining function has another name there.
_ALIASES = {"load_map": "load_grid", "save_map": "save_grid"}

__all__ = sorted([*_PUBLIC, "__version__"])


def __getattr__(name: str):
    """Load a public name on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'geofix' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), _ALIASES.get(name, name))
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names (for tab completion)."""
    return sorted(set(globals()) | set(__all__))
