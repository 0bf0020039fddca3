"""One read-only copy of the map for every spawned worker process (POSIX shared memory).

Forked workers need none of this: they inherit the calling process's read-only map,
whose pages stay shared (the map is held once). For spawned workers the calling process
copies the prepared map's values once into a shared-memory block and hands the workers
a small picklable :class:`SharedGridHandle`; each worker maps the block read-only and
wraps it in a :class:`~geofix.maps.grid.Grid` without copying, so such a campaign with
``k`` local workers holds the map twice (the calling process's copy and the shared
one), not ``k + 1`` times.

Storage precision: :func:`storage_dtype` keeps float32 when rounding the map to float32
changes no value by more than :data:`FLOAT32_SHARE_OF_NOISE` of the sensor noise (a
depth of 11 km rounds by at most 0.66 mm, so any depth sensor noisier than 6.6 cm; a
gravity anomaly of 500 mGal by at most 3e-5 mGal), else float64. The same (possibly
rounded) map is used by every backend, inline included, so a campaign's table does not
depend on the number of jobs. A metric netCDF map is read straight into that precision
(:func:`geofix.maps.io.load_grid` with ``float32_within`` = :func:`float32_within`), the
same values as rounding a float64 read.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from geofix.errors import MapError
from geofix.maps.grid import Grid
from geofix.maps.io import float32_rounding
from geofix.sim.scenario import Scenario
from geofix.sim.simulate import prepare_map

FLOAT32_SHARE_OF_NOISE = 0.01
"""Largest float32 rounding error allowed, as a share of the sensor noise 1-sigma: the
rounding then adds less than 1e-4 of the noise variance to any read."""

_ATTACHED: list[shared_memory.SharedMemory] = []  # kept open for the life of a worker


@dataclass(frozen=True)
class SharedGridHandle:
    """What a worker needs to map the shared map: block name, layout, grid fields."""

    block: str
    shape: tuple[int, int]
    dtype: str
    fields: dict


def storage_dtype(values: np.ndarray, noise_std: float) -> np.dtype:
    """float32 when its rounding error is negligible against ``noise_std``, else float64.

    Parameters
    ----------
    values : numpy.ndarray
        Map values (NaN = no data).
    noise_std : float
        Smallest sensor noise 1-sigma, map units (0 keeps float64).

    Returns
    -------
    numpy.dtype
        ``float32`` or ``float64``.
    """
    if values.dtype == np.float32:
        return np.dtype(np.float32)
    within = float32_within(noise_std)
    if within is None:
        return np.dtype(np.float64)
    # the largest magnitude from two reductions: no full-map temporary such as |values|
    low, high = np.fmin.reduce(values, axis=None), np.fmax.reduce(values, axis=None)
    peak = max(abs(float(low)), abs(float(high))) if high == high else 0.0
    return np.dtype(np.float32 if float32_rounding(peak) <= within else np.float64)


def float32_within(noise_std: float) -> float | None:
    """The float32 rounding allowed for a sensor noise, map units (None: keep float64)."""
    return FLOAT32_SHARE_OF_NOISE * float(noise_std) if noise_std > 0 else None


class SharedGrid:
    """The map in a shared-memory block, owned by the calling process.

    Use as a context manager: the block is unlinked on exit. ``handle`` is what
    :func:`attach` needs in a worker.
    """

    def __init__(self, grid: Grid, dtype=np.float64) -> None:
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(grid.shape)) * dtype.itemsize
        try:
            self._block = shared_memory.SharedMemory(create=True, size=max(nbytes, 1))
        except OSError as exc:
            raise MapError(
                f"map {grid.name!r}: cannot allocate {nbytes / 1e9:.2f} GB of shared memory "
                f"for the workers ({exc}); run with --jobs 1"
            ) from None
        values = np.ndarray(grid.shape, dtype=dtype, buffer=self._block.buf)
        values[...] = grid.values
        del values  # no view may outlive the block
        fields = _grid_fields(grid)
        self.handle = SharedGridHandle(self._block.name, grid.shape, dtype.str, fields)

    def __enter__(self) -> SharedGrid:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release and unlink the block (workers keep their mapping until they exit)."""
        self._block.close()
        with contextlib.suppress(FileNotFoundError):
            self._block.unlink()


def attach(handle: SharedGridHandle) -> Grid:
    """The shared map as a read-only :class:`Grid` in a worker (no copy)."""
    block = shared_memory.SharedMemory(name=handle.block)
    _ATTACHED.append(block)
    values = np.ndarray(handle.shape, dtype=np.dtype(handle.dtype), buffer=block.buf)
    values.flags.writeable = False
    return Grid(values, **handle.fields)


def campaign_map(scenario: Scenario) -> Grid:
    """The scenario's map as a campaign holds it (and simulates its trials on).

    Prepared once (:func:`geofix.sim.simulate.prepare_map`), read straight into float32
    where that rounds no value by more than a hundredth of the sensor noise, and stored
    so: ``simulate_trial(scenario, campaign_map(scenario), i)`` is the campaign's trial
    ``i``.
    """
    noise = scenario.sensor.noise_std
    return as_storage(prepare_map(scenario, float32_within(noise)), noise)


def as_storage(grid: Grid, noise_std: float) -> Grid:
    """``grid`` with its values rounded to :func:`storage_dtype` (itself if float64 stays)."""
    dtype = storage_dtype(grid.values, noise_std)
    if dtype == grid.values.dtype:
        return grid
    values = grid.values.astype(dtype)
    values.flags.writeable = False
    return Grid(values, **_grid_fields(grid))


def _grid_fields(grid: Grid) -> dict:
    return {
        "x0": grid.x0,
        "y0": grid.y0,
        "dx": grid.dx,
        "dy": grid.dy,
        "kind": grid.kind,
        "units": grid.units,
        "name": grid.name,
        "meta": dict(grid.meta),
    }
