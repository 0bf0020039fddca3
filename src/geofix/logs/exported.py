"""Missions from a ``geofix export`` file: the very data a campaign trial ran on."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from geofix.errors import ConfigError
from geofix.logs.mission import Mission
from geofix.maps.grid import Grid


def read_exported(path: str | Path, trial: int = 0) -> tuple[Mission, Grid]:
    """One trial of a file written by :func:`geofix.sim.export.export_trials`.

    Parameters
    ----------
    path : str or pathlib.Path
        The netCDF export.
    trial : int
        Which trial (0-based position in the file).

    Returns
    -------
    tuple
        ``(Mission, Grid)``: the mission (``nav_source = "ins"``: the free INS track is
        the navigation, the simulated truth is ``truth``; ``sigma_position`` the
        scenario's prior sigma; ``velocity`` the aiding DVL's velocity when the trial has
        one; ``meta`` holds ``noise_std``, ``map_error_std``, ``beam_noise_std``,
        ``sensor``, ``lag_s`` (the gravimeter's declared lag, seconds) and ``ins_model``
        (the navigator's :class:`~geofix.nav.errstate.InsErrorModel`, None when the
        file has none), and the map it was drawn on.

    Raises
    ------
    GeofixError
        Not a geofix export (see :func:`~geofix.sim.export.load_exported`), or no such
        trial (ConfigError).
    """
    from geofix.sim.export import load_exported

    grid, trials = load_exported(path)
    if not 0 <= int(trial) < len(trials):
        raise ConfigError(f"{path}: trial {trial} not in the file (it has {len(trials)})")
    t = trials[int(trial)]
    beams = np.empty((t.n, t.offsets.shape[0], 3))
    beams[..., :2] = t.offsets
    beams[..., 2] = t.measured
    return (
        Mission(
            times=np.asarray(t.times, dtype=float),
            nav=np.asarray(t.indicated, dtype=float),
            heading=np.asarray(t.indicated_heading, dtype=float),
            beams=beams,
            nav_source="ins",
            truth=np.asarray(t.truth, dtype=float),
            velocity=None if t.dvl_velocity is None else np.asarray(t.dvl_velocity, float),
            sigma_position=np.asarray(t.sigma_position, dtype=float),
            frame=grid.meta.get("projection"),
            kind=grid.kind,
            name=f"{Path(path).stem}#{t.index}",
            meta={
                "source": Path(path).name,
                "reader": "export",
                "trial": int(t.index),
                "sensor": t.sensor,
                "noise_std": float(t.noise_std),
                "map_error_std": float(t.map_error_std),
                "beam_noise_std": t.beam_noise_std,
                "lag_s": float(t.lag_s),
                "ins_model": t.ins_model,
            },
        ),
        grid,
    )
