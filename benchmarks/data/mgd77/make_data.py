"""Cut the bundled cruise excerpts and ETOPO1 crops from the full files (run once).

The full NOAA MGD77T cruise files and the global 10 arc-minute grids are not part of the
project. Given a folder that holds them (``mgd77/<cruise>.m77t``,
``global/earth-topography-10arcmin.nc``, ``global/earth-gravity-10arcmin.nc`` and
``global/earth-geoid-10arcmin.nc``), this
script rewrites every file of this folder that PROVENANCE.md lists, or only the gravity
crops with ``--gravity`` (the gravity anomaly needs ``boule``, the ``data`` extra)::

    python benchmarks/data/mgd77/make_data.py DATA_FOLDER [--gravity]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

EXCERPTS = {"ew0007": (44551, 46711), "ew0102": (2843, 5003), "ew0112": (21469, 23630)}
"""Cruise -> first and last 0-based data record of the excerpt (36 h of deep-water transit
each, the longest distance steamed in 36 h with every depth below 1000 m)."""

MARGIN_DEG = 1.5
"""ETOPO1 kept around each excerpt's track, degrees (INS drift and filter spread)."""

STEP_DEG = 1.0 / 6.0
"""ETOPO1 node spacing, degrees (10 arc-minutes)."""


def cut_excerpt(source: Path, first: int, last: int, out: Path | None) -> tuple[float, ...]:
    """Copy the header line and data records ``first .. last`` byte for byte (None: no copy).

    Returns
    -------
    tuple of float
        ``(west, east, south, north)`` of the excerpt's positions, degrees.
    """
    with source.open("rb") as handle:
        lines = handle.readlines()
    chosen = lines[1 + first : 2 + last]
    if out is not None:
        out.write_bytes(lines[0] + b"".join(chosen))
    header = lines[0].decode("latin-1").rstrip("\r\n").split("\t")
    lat_at, lon_at = header.index("LAT"), header.index("LON")
    lat, lon = [], []
    for line in chosen:
        cells = line.decode("latin-1").rstrip("\r\n").split("\t")
        try:
            lat.append(float(cells[lat_at]))
            lon.append(float(cells[lon_at]))
        except (IndexError, ValueError):
            continue
    return min(lon), max(lon), min(lat), max(lat)


def crop_etopo(source: Path, box: tuple[float, ...], out: Path) -> None:
    """The ETOPO1 nodes within ``MARGIN_DEG`` of ``box``, in float32."""
    import xarray as xr

    west, east, south, north = _snapped(box)
    with xr.open_dataset(source) as ds:
        crop = ds.sel(
            longitude=slice(west - 1e-6, east + 1e-6), latitude=slice(south - 1e-6, north + 1e-6)
        ).load()
    crop["topography"] = crop["topography"].astype("float32")
    crop.attrs = {
        "title": f"ETOPO1 at 10 arc-minutes, cropped to {west:g}..{east:g} E, "
        f"{south:g}..{north:g} N",
        "source": "fatiando/data earth-topography-10arcmin (ETOPO1, NOAA NCEI), public domain",
    }
    crop.to_netcdf(out)


def _snapped(box: tuple[float, ...]) -> tuple[float, ...]:
    """``box`` grown by ``MARGIN_DEG`` and snapped outwards to the 10' lattice, degrees."""
    west, east, south, north = box
    snap = lambda v, f: float(f(v / STEP_DEG) * STEP_DEG)  # noqa: E731
    west, south = snap(west - MARGIN_DEG, np.floor), snap(south - MARGIN_DEG, np.floor)
    east, north = snap(east + MARGIN_DEG, np.ceil), snap(north + MARGIN_DEG, np.ceil)
    return west, east, south, north


#: The level's 1-sigma the gravity crops state (``offset_std``, mGal): a shipboard free-air
#: anomaly's reference formula and datum (1930 with Potsdam against 1980: up to about 25
#: mGal at these latitudes) and its gravimeter's base tie (a few mGal), fixed before any
#: replay on these maps.
GRAVITY_OFFSET_STD = 25.0


def crop_gravity(source: Path, geoid: Path, box: tuple[float, ...], out: Path) -> None:
    """The free-air gravity anomaly at the grid's height over the nodes of the ETOPO1 crop.

    fatiando/data's grid is EIGEN-6C4's gravity (mGal) at 10 km above the ellipsoid. The
    anomaly is that minus WGS84's normal gravity at the point the geoid height ``N`` below
    it (boule's closed form: no free-air reduction), ``N`` from the same model's geoid
    grid; float32, stating :data:`GRAVITY_OFFSET_STD`.
    """
    import boule
    import xarray as xr

    west, east, south, north = _snapped(box)
    window = {
        "longitude": slice(west - 1e-6, east + 1e-6),
        "latitude": slice(south - 1e-6, north + 1e-6),
    }
    with xr.open_dataset(source) as ds:
        crop = ds.sel(window).load()
    with xr.open_dataset(geoid) as ds:
        undulation = ds["geoid"].sel(window).values.astype(float)
    height = crop["height"].values.astype(float) - undulation
    lat = np.broadcast_to(crop["latitude"].values[:, None], height.shape)
    lon = np.broadcast_to(crop["longitude"].values[None, :], height.shape)
    normal = boule.WGS84.normal_gravity((lon, lat, height))
    anomaly = (crop["gravity"].values - normal).astype("float32")
    out_ds = xr.Dataset(
        {"free_air_anomaly": (("latitude", "longitude"), anomaly)},
        coords={"latitude": crop["latitude"].values, "longitude": crop["longitude"].values},
    )
    out_ds["free_air_anomaly"].attrs = {
        "units": "mGal",
        "long_name": "free-air gravity anomaly at 10 km above the WGS84 ellipsoid",
    }
    out_ds.attrs = {
        "title": f"EIGEN-6C4 free-air anomaly at 10 km height, 10 arc-minutes, cropped to "
        f"{west:g}..{east:g} E, {south:g}..{north:g} N",
        "source": "fatiando/data earth-gravity-10arcmin and earth-geoid-10arcmin (EIGEN-6C4, "
        "GFZ ICGEM, CC-BY 4.0); WGS84 normal gravity (boule)",
        "offset_std": GRAVITY_OFFSET_STD,
    }
    out_ds.to_netcdf(out)


def main(source: Path, gravity_only: bool = False) -> None:
    """Write every excerpt and crop of this folder from the full files in ``source``."""
    for cruise, (first, last) in EXCERPTS.items():
        excerpt = HERE / f"{cruise}_excerpt.m77t"
        if gravity_only:
            box = cut_excerpt(source / "mgd77" / f"{cruise}.m77t", first, last, None)
        else:
            box = cut_excerpt(source / "mgd77" / f"{cruise}.m77t", first, last, excerpt)
            topo = source / "global" / "earth-topography-10arcmin.nc"
            crop_etopo(topo, box, HERE / f"etopo1_10min_{cruise}.nc")
        grav = source / "global" / "earth-gravity-10arcmin.nc"
        geoid = source / "global" / "earth-geoid-10arcmin.nc"
        crop_gravity(grav, geoid, box, HERE / f"eigen6c4_10min_{cruise}.nc")
        print(cruise, excerpt.stat().st_size, "bytes;", "box", box)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--gravity"]
    if len(args) != 1:
        sys.exit("usage: python benchmarks/data/mgd77/make_data.py DATA_FOLDER [--gravity]")
    main(Path(args[0]), gravity_only="--gravity" in sys.argv)
