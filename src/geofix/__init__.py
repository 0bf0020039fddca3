"""geofix: keep an underwater vehicle's position true without GPS.

Terrain- and gravity-aided navigation: match what the vehicle measures (echosounder
depths, gravimeter anomalies) against a prior map to correct INS drift. See
:mod:`geofix.conventions` for frames, angles and units.
"""

from geofix.errors import (
    ConfigError,
    GeofixError,
    InputError,
    MapError,
    MatchError,
    TrackOffMapError,
)
from geofix.maps.grid import Grid
from geofix.match.base import Fix, Matcher, MatchProblem

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "Fix",
    "GeofixError",
    "Grid",
    "InputError",
    "MapError",
    "MatchError",
    "MatchProblem",
    "Matcher",
    "Navigator",
    "TrackOffMapError",
    "__version__",
]


def __getattr__(name: str):
    """``geofix.Navigator`` is imported on first use (it pulls in the method registry)."""
    if name == "Navigator":
        from geofix.navigator import Navigator

        return Navigator
    raise AttributeError(f"module 'geofix' has no attribute {name!r}")
