"""geofix: keep an underwater vehicle's position true without GPS.

Terrain- and gravity-aided navigation: match what the vehicle measures (echosounder
depths, gravimeter anomalies) against a prior map to correct INS drift. See
:mod:`geofix.conventions` for frames, angles and units.
"""

from geofix._version import __version__
from geofix.errors import ConfigError, GeofixError, MapError, MatchError, TrackOffMapError
from geofix.maps.grid import Grid
from geofix.problem import Fix, Matcher, MatchProblem

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
