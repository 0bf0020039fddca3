"""Cut the bundled cruise excerpts and ETOPO1 crops from the full files (run once).

The full NOAA MGD77T cruise files and the global ETOPO1 10 arc-minute grid are not part of
the project. Given a folder that holds them (``mgd77/<cruise>.m77t`` and
``global/earth-topography-10arcmin.nc``), this script rewrites every file of this folder
that PROVENANCE.md lists::

    python benchmarks/data/mgd77/make_data.py DATA_FOLDER
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


def cut_excerpt(source: Path, first: int, last: int, out: Path) -> tuple[float, ...]:
    """Copy the header line and data records ``first .. last`` byte for byte.

    Returns
    -------
    tuple of float
        ``(west, east, south, north)`` of the excerpt's positions, degrees.
    """
    with source.open("rb") as handle:
        lines = handle.readlines()
    chosen = lines[1 + first : 2 + last]
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

    west, east, south, north = box
    snap = lambda v, f: float(f(v / STEP_DEG) * STEP_DEG)  # noqa: E731
    west, south = snap(west - MARGIN_DEG, np.floor), snap(south - MARGIN_DEG, np.floor)
    east, north = snap(east + MARGIN_DEG, np.ceil), snap(north + MARGIN_DEG, np.ceil)
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


def main(source: Path) -> None:
    """Write every excerpt and crop of this folder from the full files in ``source``."""
    for cruise, (first, last) in EXCERPTS.items():
        excerpt = HERE / f"{cruise}_excerpt.m77t"
        box = cut_excerpt(source / "mgd77" / f"{cruise}.m77t", first, last, excerpt)
        topo = source / "global" / "earth-topography-10arcmin.nc"
        crop_etopo(topo, box, HERE / f"etopo1_10min_{cruise}.nc")
        print(cruise, excerpt.stat().st_size, "bytes;", "box", box)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python benchmarks/data/mgd77/make_data.py DATA_FOLDER")
    main(Path(sys.argv[1]))
