"""geofix: keep an underwater vehicle's position true without GPS.

Terrain- and gravity-aided navigation: match what the vehicle measures (echosounder
depths, gravimeter anomalies) against a prior map to correct INS drift. See
:mod:`geofix.conventions` for frames, angles and units.
"""

from geofix import _lifetime

_lifetime.arm_in_spawned_worker()  # first: a worker starting up dies with its parent

from geofix.errors import (  # noqa: E402
    ConfigError,
    GeofixError,
    MapError,
    MatchError,
    TrackOffMapError,
)
from geofix.maps.grid import Grid  # noqa: E402
from geofix.match.base import Fix, Matcher, MatchProblem  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "ConfigError",
    "Fix",
    "GeofixError",
    "Grid",
    "MapError",
    "MatchError",
    "MatchProblem",
    "Matcher",
    "TrackOffMapError",
    "__version__",
]
