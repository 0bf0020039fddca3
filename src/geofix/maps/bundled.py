"""Maps shipped with geofix, addressed as ``builtin:NAME`` (see ``maps/data/PROVENANCE.md``)."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from types import MappingProxyType

from geofix.errors import MapError

BUILTIN_PREFIX = "builtin:"


@dataclass(frozen=True)
class BundledMap:
    """One map file shipped inside the package.

    Parameters
    ----------
    file : str
        File name inside ``geofix/maps/data``.
    description : str
        What the map shows, its grid and its value range.
    licence : str
        Licence under which the file is redistributed.
    source : str
        Where the file comes from.
    kind : str
        Field kind when the file itself does not say: ``"depth"`` or ``"gravity"``.
    """

    file: str
    description: str
    licence: str
    source: str
    kind: str = "depth"


_GMT_SERVER = "GenericMappingTools/gmtserver-admin (GMT remote-data cache)"

BUNDLED_MAPS = MappingProxyType(
    {
        "azores": BundledMap(
            file="bathy_1m.nc",
            description="Bathymetry and topography around the Azores (islands > 0), 1 arc-minute "
            "lon/lat grid, 601 x 451 cells, lon -33..-23, lat 35.5..43, -5158..1117 m",
            licence="LGPL-3.0 (repository licence)",
            source=f"{_GMT_SERVER}, cache/bathy_1m.nc",
        ),
        "alaska_gravity": BundledMap(
            file="AK_gulf_grav.nc",
            description="Sandwell & Smith free-air gravity anomaly, Gulf of Alaska (Pratt "
            "seamount chain), 2 arc-minute lon/lat grid, 420 x 165 cells, -107.4..189.9 mGal",
            licence="LGPL-3.0 (repository licence)",
            source=f"{_GMT_SERVER}, GMT example 18 data",
            kind="gravity",
        ),
        "mb_1km": BundledMap(
            file="mb.par.surf.1km.sq.nc",
            description="Multibeam bathymetry on a projected 1000 m grid, 160 x 160 cells, "
            "-5021..-2200 m",
            licence="LGPL-3.0 (repository licence)",
            source=f"{_GMT_SERVER}, GMT example 37 data",
        ),
        "grav_1km": BundledMap(
            file="grav.V18.par.surf.1km.sq.nc",
            description="Sandwell & Smith V18 satellite-altimetry gravity anomaly on the same "
            "projected 1000 m grid as mb_1km, 160 x 160 cells, -60.0..33.8 mGal",
            licence="LGPL-3.0 (repository licence)",
            source=f"{_GMT_SERVER}, GMT example 37 data",
            kind="gravity",
        ),
        "navo_flat": BundledMap(
            file="JD211_public_Release_1-4_UTM.bag",
            description="NAVO survey of a nearly flat seafloor (std 0.3 m), BAG 1.4, UTM zone 2, "
            "1478 x 1707 cells at 2 m, 46 % valid, -52.96..-50.99 m",
            licence="BSD-3-Clause",
            source="OpenNavigationSurface/BAG, examples/sample-data/NAVO_data",
        ),
        "deep_nans": BundledMap(
            file="data_w_nans.nc",
            description="Deep-sea multibeam bathymetry with everything shallower than 4100 m "
            "set to NaN (51 % NaN), 0.001 degree lon/lat grid, 1000 x 800 cells, -4719..-4100 m",
            licence="LGPL-3.0 (repository licence)",
            source=f"{_GMT_SERVER}, cache/data_w_nans.nc",
        ),
    }
)


def bundled_maps() -> MappingProxyType:
    """The table of bundled maps.

    Returns
    -------
    mapping of str to BundledMap
        Read-only mapping from the builtin name (used as ``builtin:NAME``) to its entry.
    """
    return BUNDLED_MAPS


def builtin_name(name: str) -> str:
    """The bare builtin name of ``name`` or ``builtin:name``; MapError if unknown."""
    bare = name.removeprefix(BUILTIN_PREFIX)
    if bare not in BUNDLED_MAPS:
        known = ", ".join(sorted(BUNDLED_MAPS))
        raise MapError(f"unknown builtin map {bare!r}; known maps: {known}")
    return bare


def builtin_path(name: str) -> Path:
    """Path of the packaged file of a bundled map.

    Parameters
    ----------
    name : str
        A bundled map name, with or without the ``builtin:`` prefix.

    Returns
    -------
    pathlib.Path
        The file inside the installed package.

    Raises
    ------
    MapError
        If ``name`` is not a bundled map (the message lists the known names).
    """
    entry = BUNDLED_MAPS[builtin_name(name)]
    return Path(str(resources.files("geofix.maps").joinpath("data", entry.file)))
