"""Export simulated trials to a self-describing netCDF file, and read them back.

The file holds everything a method sees and everything it is judged against, so that
other tools can be run on the very same data:

- the map: ``z (y, x)`` on metric cell-centre coordinates, with the :class:`Grid`
  geometry in the attributes ``grid_x0, grid_y0, grid_dx, grid_dy, grid_kind, grid_units,
  grid_name, grid_meta_json``;
- per trial and sample: ``truth_x, truth_y, true_heading, indicated_x, indicated_y,
  indicated_heading, times, sigma_position`` ``(trial, sample)`` and ``measured``
  ``(trial, sample, beam)``;
- the sensor geometry ``offset_across, offset_along (beam)``, the legs ``leg_start
  (leg)`` and per trial ``noise_std, map_error_std, trial_index``; the per-beam noise
  ``beam_noise_std (trial, beam)`` when any trial has one (NaN rows for trials without);
- every optional array of a trial (``dvl_velocity``, ``true_velocity``,
  ``unlagged_measured``) as ``extra_<key>[_x|_y]`` and ``lag_s`` per trial, each
  tagged with attributes ``extra_key`` / ``extra_component`` so the reader restores them;
- with a ``seabed:`` block (:mod:`geofix.sim.seabed`), the prior maps the methods got:
  ``prior_z`` on its own metric cell-centre coordinates ``prior_x, prior_y``, with
  dimensions ``(prior_y, prior_x)`` when every trial has the same prior and ``(trial,
  prior_y, prior_x)`` otherwise; its geometry in the attributes ``prior_grid_x0,
  prior_grid_y0, prior_grid_dx, prior_grid_dy, prior_grid_name, prior_grid_meta_json``
  (kind and units those of ``z``; ``registration_std_m`` in the meta when the block
  gives it), and the drawn misregistration ``prior_shift_x, prior_shift_y (trial)``,
  metres (truth). ``z`` is then the seabed the sensor read (without the relief);
- global attributes: the scenario as YAML (``scenario_yaml``), its name, seed, sensor
  type and conventions; the navigator's INS error model
  (:class:`~geofix.nav.errstate.InsErrorModel`, SI units) as JSON (``ins_model_json``)
  when the trials have one, so that the error-state filters (``mpf``,
  ``pmf:model=errstate``) run on the file's trials. Units are on every variable (metres,
  radians clockwise from north, seconds, map units);
- with a ``sensors:`` list, every field after the first as ``field<i>_*`` (``i`` its
  index in the list, from 1) and the global attribute ``geofix_fields`` (their number):
  its map ``field<i>_z (field<i>_y, field<i>_x)`` on its own coordinates, the geometry,
  kind, units, name, sensor type and lag in that variable's attributes (``grid_x0``,
  ``grid_y0``, ``grid_dx``, ``grid_dy``, ``grid_kind``, ``grid_units``, ``grid_name``,
  ``grid_meta_json``, ``sensor``, ``lag_s``); ``field<i>_measured (trial, sample,
  field<i>_beam)``, ``field<i>_offset_across``, ``field<i>_offset_along (field<i>_beam)``,
  ``field<i>_noise_std (trial)``, ``field<i>_beam_noise_std (trial, field<i>_beam)`` and,
  with a lag, ``field<i>_unlagged_measured``; with a ``seabed`` block in its entry, the
  prior maps ``field<i>_prior_z (trial, field<i>_prior_y, field<i>_prior_x)`` (geometry
  in its attributes) and ``field<i>_prior_shift_x``, ``field<i>_prior_shift_y (trial)``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from geofix._atomic import write_atomic
from geofix.errors import ConfigError, GeofixError
from geofix.maps.grid import Grid
from geofix.memory import cells_bytes, check_allocation
from geofix.nav.errstate import InsErrorModel
from geofix.sim.scenario import with_overrides
from geofix.sim.seabed import prior_shape
from geofix.sim.trial import Trial, TrialField

# One dataset variable as xarray takes it: ``(dims, values, attributes)``.
_Variable = tuple[str | tuple[str, ...], ArrayLike, dict[str, Any]]

_RAD = "radians clockwise from north"
_TRACKS = {
    "truth": ("truth", "true position", "m"),
    "indicated": ("indicated", "INS-indicated position", "m"),
}
_SAMPLE_VARS = {
    "true_heading": ("true heading", _RAD),
    "indicated_heading": ("INS-indicated heading", _RAD),
    "times": ("sample time from the start", "s"),
    "sigma_position": ("prior per-axis 1-sigma of the INS position error", "m"),
}


def export_trials(scenario, path: str | Path, trials: int | None = None, seed=None) -> Path:
    """Simulate the first ``trials`` trials of a scenario and write them to netCDF.

    Parameters
    ----------
    scenario : Scenario
        The mission family.
    path : str or pathlib.Path
        Output file (netCDF-4).
    trials, seed : int, optional
        Override the scenario's number of trials and seed.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    GeofixError
        ``trials`` below 1 (ConfigError), a track off the map (TrackOffMapError), a bad
        map (MapError), prior maps beyond the memory budget (MemoryBudgetError), or the
        file cannot be written.
    """
    from geofix.sim.simulate import prepare_field_maps, prepare_map, simulate_trial

    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"--out {path} is a folder; give the netCDF file to write")
    scenario = with_overrides(scenario, trials, seed)
    grid = prepare_map(scenario)
    if scenario.seabed is not None:
        shape = prior_shape(grid.shape, scenario.seabed.cell_factor)
        _check_priors_size(scenario.trials, shape)
    runs = [simulate_trial(scenario, grid, i) for i in range(scenario.trials)]
    dataset = trials_dataset(grid, runs, _scenario_attrs(scenario), prepare_field_maps(scenario))
    return write_atomic(path, dataset.to_netcdf)  # whole or absent


def _scenario_attrs(scenario) -> dict:
    import yaml

    data = scenario.model_dump(mode="json", exclude={"base_dir"})
    return {
        "scenario_yaml": yaml.safe_dump(data, sort_keys=False),
        "scenario_name": scenario.name,
        "scenario_seed": int(scenario.seed),
    }


def trials_dataset(grid: Grid, trials: list[Trial], attrs: dict | None = None, field_maps=None):
    """The :mod:`xarray` dataset of a map and trials of equal length and beams.

    Parameters
    ----------
    grid : Grid
        The map the trials were drawn on.
    trials : list of Trial
        At least one trial; all with the same samples, beams, offsets and legs (and the
        same further fields).
    attrs : dict, optional
        Extra global attributes (e.g. the scenario YAML).
    field_maps : sequence of Grid, optional
        The maps the further fields were drawn on (default: the first trial's field
        maps, which are those maps unless an entry has a ``seabed`` block).

    Returns
    -------
    xarray.Dataset
        See the module docstring for the variables.
    """
    import xarray as xr

    _check_alike(trials)
    first = trials[0]
    data: dict[str, _Variable] = {
        "z": (("y", "x"), np.asarray(grid.values), {"units": grid.units, "long_name": "map"})
    }
    data.update(_trial_vars(trials))
    data.update(_extra_vars(trials))
    data["offset_across"] = ("beam", first.offsets[:, 0], _attrs("beam offset, starboard", "m"))
    data["offset_along"] = ("beam", first.offsets[:, 1], _attrs("beam offset, forward", "m"))
    data["leg_start"] = ("leg", np.asarray(first.leg_starts), _attrs("first sample of leg", "1"))
    coords = {"x": ("x", grid.x, {"units": "m"}), "y": ("y", grid.y, {"units": "m"})}
    global_attrs = {**_global_attrs(grid, first), **(attrs or {})}
    prior = _prior_vars(trials)
    if prior is not None:
        prior_data, prior_coords, prior_attrs = prior
        data.update(prior_data)
        coords.update(prior_coords)
        global_attrs.update(prior_attrs)
    if first.fields:
        maps = field_maps if field_maps is not None else [f.grid for f in first.fields]
        for i, field_map in enumerate(maps, start=1):
            field_data, field_coords = _field_vars(trials, i, field_map)
            data.update(field_data)
            coords.update(field_coords)
        global_attrs["geofix_fields"] = len(first.fields)
    return xr.Dataset(data, coords=coords, attrs=global_attrs)


def _grid_attrs(grid: Grid) -> dict:
    return {
        "grid_x0": float(grid.x0),
        "grid_y0": float(grid.y0),
        "grid_dx": float(grid.dx),
        "grid_dy": float(grid.dy),
        "grid_kind": grid.kind,
        "grid_units": grid.units,
        "grid_name": grid.name,
        "grid_meta_json": json.dumps(grid.meta, default=str),
    }


def _field_vars(trials: list[Trial], i: int, field_map: Grid) -> tuple[dict, dict]:
    """``(variables, coordinates)`` of further field ``i`` (1-based) of every trial."""
    name, beam = f"field{i}", f"field{i}_beam"
    fields = [t.fields[i - 1] for t in trials]
    first = fields[0]
    units = field_map.units
    data: dict[str, _Variable] = {
        f"{name}_z": (
            (f"{name}_y", f"{name}_x"),
            np.asarray(field_map.values),
            {
                "units": units,
                "long_name": f"map of field {i}",
                "sensor": first.sensor,
                "lag_s": float(first.lag_s),
                **_grid_attrs(field_map),
            },
        ),
        f"{name}_measured": (
            ("trial", "sample", beam),
            np.stack([f.measured for f in fields]),
            _attrs(f"field {i} sensor reading", units),
        ),
        f"{name}_offset_across": (beam, first.offsets[:, 0], _attrs("beam offset, starboard", "m")),
        f"{name}_offset_along": (beam, first.offsets[:, 1], _attrs("beam offset, forward", "m")),
        f"{name}_noise_std": (
            "trial",
            [float(f.noise_std) for f in fields],
            _attrs("sensor noise 1-sigma", units),
        ),
        f"{name}_beam_noise_std": (
            ("trial", beam),
            np.stack([np.asarray(f.beam_noise_std, float) for f in fields]),
            _attrs("sensor noise 1-sigma of every beam", units),
        ),
    }
    coords = {
        f"{name}_x": (f"{name}_x", field_map.x, {"units": "m"}),
        f"{name}_y": (f"{name}_y", field_map.y, {"units": "m"}),
    }
    if first.unlagged_measured is not None:
        stacked = np.stack([np.asarray(f.unlagged_measured) for f in fields])
        what = _attrs(f"field {i} reading before the lag", units)
        data[f"{name}_unlagged_measured"] = (("trial", "sample", beam), stacked, what)
    if first.sensed is not None:
        prior = first.grid
        stacked = np.stack([np.asarray(f.grid.values) for f in fields])
        what = {"units": units, "long_name": f"prior map of field {i}", **_grid_attrs(prior)}
        data[f"{name}_prior_z"] = (("trial", f"{name}_prior_y", f"{name}_prior_x"), stacked, what)
        shifts = np.stack(
            [np.zeros(2) if f.prior_shift_m is None else f.prior_shift_m for f in fields]
        )
        for c, axis in enumerate(("x", "y")):
            what = _attrs(f"field {i} prior map misregistration, {axis}", "m")
            data[f"{name}_prior_shift_{axis}"] = ("trial", shifts[:, c], what)
        coords[f"{name}_prior_x"] = (f"{name}_prior_x", prior.x, {"units": "m"})
        coords[f"{name}_prior_y"] = (f"{name}_prior_y", prior.y, {"units": "m"})
    return data, coords


def _attrs(long_name: str, units: str) -> dict:
    return {"long_name": long_name, "units": units}


def _trial_vars(trials: list[Trial]) -> dict[str, _Variable]:
    out: dict[str, _Variable] = {}
    for name, (attr, what, units) in _TRACKS.items():
        stacked = np.stack([getattr(t, attr) for t in trials])
        out[f"{name}_x"] = (("trial", "sample"), stacked[..., 0], _attrs(f"{what}, east", units))
        out[f"{name}_y"] = (("trial", "sample"), stacked[..., 1], _attrs(f"{what}, north", units))
    for name, (what, units) in _SAMPLE_VARS.items():
        stacked = np.stack([getattr(t, name) for t in trials])
        out[name] = (("trial", "sample"), stacked, _attrs(what, units))
    measured = np.stack([t.measured for t in trials])
    out["measured"] = (("trial", "sample", "beam"), measured, _attrs("sensor reading", "map"))
    for name, what in (("noise_std", "sensor noise 1-sigma"), ("map_error_std", "map error")):
        out[name] = ("trial", [float(getattr(t, name)) for t in trials], _attrs(what, "map"))
    out["trial_index"] = ("trial", [int(t.index) for t in trials], _attrs("trial number", "1"))
    out.update(_beam_noise_std_vars(trials))
    return out


def _beam_noise_std_vars(trials: list[Trial]) -> dict[str, _Variable]:
    """``beam_noise_std (trial, beam)``, NaN rows for trials without; none if no trial has it."""
    if all(t.beam_noise_std is None for t in trials):
        return {}
    beams = trials[0].offsets.shape[0]
    rows = [
        np.full(beams, np.nan) if t.beam_noise_std is None else np.asarray(t.beam_noise_std, float)
        for t in trials
    ]
    what = _attrs("sensor noise 1-sigma of every beam", "map")
    return {"beam_noise_std": (("trial", "beam"), np.stack(rows), what)}


def _extra_vars(trials: list[Trial]) -> dict[str, _Variable]:
    out: dict[str, _Variable] = {}
    first = trials[0]
    for key, value in _optional_fields(first).items():
        stacked = np.stack([np.asarray(getattr(t, key), dtype=float) for t in trials])
        tag = {"extra_key": key}
        if stacked.ndim == 1:
            out[f"extra_{key}"] = ("trial", stacked, {**tag, "extra_component": "scalar"})
        elif stacked.ndim == 2:
            out[f"extra_{key}"] = (("trial", "sample"), stacked, {**tag, "extra_component": "n"})
        elif stacked.shape[-1] == 2 and np.asarray(value).shape[-1] != first.offsets.shape[0]:
            for c, axis in enumerate(("x", "y")):
                attrs = {**tag, "extra_component": axis}
                out[f"extra_{key}_{axis}"] = (("trial", "sample"), stacked[..., c], attrs)
        else:
            dims = ("trial", "sample", "beam")
            out[f"extra_{key}"] = (dims, stacked, {**tag, "extra_component": "beams"})
    return out


def _check_priors_size(trials: int, shape: tuple[int, int]) -> None:
    """Refuse prior maps of ``trials`` trials that would not fit the memory budget."""
    check_allocation(
        cells_bytes(trials, shape[0], shape[1], copies=2),
        f"prior maps of {trials} trials ({shape[0]} x {shape[1]} cells each; seabed block)",
    )


def _prior_vars(trials: list[Trial]) -> tuple[dict, dict, dict] | None:
    """``(variables, coordinates, attributes)`` of the trials' prior maps; None without."""
    if all(t.prior_map is None for t in trials):
        return None
    priors = [t.prior_map for t in trials if t.prior_map is not None]
    if len(priors) != len(trials):
        raise GeofixError("trials to export must all have a prior map, or none")
    first = priors[0]
    geometry = (first.shape, first.x0, first.y0, first.dx, first.dy)
    for p in priors[1:]:
        if (p.shape, p.x0, p.y0, p.dx, p.dy) != geometry:
            raise GeofixError("trials to export must share one prior map geometry")
    _check_priors_size(len(priors), first.shape)
    what = {"units": first.units, "long_name": "prior map the methods got"}
    same = all(p is first or np.array_equal(p.values, first.values, equal_nan=True) for p in priors)
    if same:
        values: _Variable = (("prior_y", "prior_x"), np.asarray(first.values), what)
    else:
        stacked = np.stack([np.asarray(p.values) for p in priors])
        values = (("trial", "prior_y", "prior_x"), stacked, what)
    shifts = np.stack([_shift(t) for t in trials])
    data: dict[str, _Variable] = {
        "prior_z": values,
        "prior_shift_x": ("trial", shifts[:, 0], _attrs("prior map misregistration, east", "m")),
        "prior_shift_y": ("trial", shifts[:, 1], _attrs("prior map misregistration, north", "m")),
    }
    coords = {
        "prior_x": ("prior_x", first.x, {"units": "m"}),
        "prior_y": ("prior_y", first.y, {"units": "m"}),
    }
    attrs = {
        "prior_grid_x0": float(first.x0),
        "prior_grid_y0": float(first.y0),
        "prior_grid_dx": float(first.dx),
        "prior_grid_dy": float(first.dy),
        "prior_grid_name": first.name,
        "prior_grid_meta_json": json.dumps(first.meta, default=str),
    }
    return data, coords, attrs


def _shift(trial: Trial) -> np.ndarray:
    """The trial's drawn prior misregistration, metres (zero when none is recorded)."""
    return np.zeros(2) if trial.prior_shift_m is None else np.asarray(trial.prior_shift_m, float)


def _global_attrs(grid: Grid, first: Trial) -> dict:
    ins = {} if first.ins_model is None else {"ins_model_json": _ins_model_json(first.ins_model)}
    return ins | {
        "geofix_trials": 1,
        "Conventions": "x east, y north (metres, local frame); headings radians clockwise "
        "from north; row 0 of z at the south; measured in map units (same sign as z)",
        "sensor": first.sensor,
        "grid_x0": float(grid.x0),
        "grid_y0": float(grid.y0),
        "grid_dx": float(grid.dx),
        "grid_dy": float(grid.dy),
        "grid_kind": grid.kind,
        "grid_units": grid.units,
        "grid_name": grid.name,
        "grid_meta_json": json.dumps(grid.meta, default=str),
    }


def _ins_model_json(model: InsErrorModel) -> str:
    return json.dumps(model.to_dict())


def _ins_model_from(ds) -> InsErrorModel | None:
    """The ``ins_model_json`` attribute back as a model (None in a file without one)."""
    text = ds.attrs.get("ins_model_json")
    if text is None:
        return None
    try:
        return InsErrorModel.from_dict(json.loads(text))
    except (ValueError, ConfigError) as exc:
        raise GeofixError(f"bad ins_model_json attribute in the trials export: {exc}") from None


def _check_alike(trials: list[Trial]) -> None:
    if not trials:
        raise GeofixError("no trials to export")
    first = trials[0]
    for t in trials[1:]:
        if t.measured.shape != first.measured.shape or t.leg_starts != first.leg_starts:
            raise GeofixError("trials to export must have the same samples, beams and legs")
        if t.ins_model != first.ins_model:
            raise GeofixError("trials to export must share one INS error model")
        shapes = [f.measured.shape for f in t.fields]
        if shapes != [f.measured.shape for f in first.fields]:
            raise GeofixError("trials to export must have the same further fields")


def load_exported(path: str | Path) -> tuple[Grid, list[Trial]]:
    """Read a file written by :func:`export_trials` back into a map and trials.

    Parameters
    ----------
    path : str or pathlib.Path
        The netCDF file.

    Returns
    -------
    tuple
        ``(Grid, [Trial, ...])``, equal to what was exported (tuples in the grid's
        ``meta`` come back as lists), ``ins_model`` included when the file has one and
        each trial's ``prior_map`` and ``prior_shift_m`` when it has prior maps.

    Raises
    ------
    GeofixError
        The file is missing, unreadable, or not a geofix trials export.
    """
    import xarray as xr

    try:
        with xr.open_dataset(path) as opened:
            ds = opened.load()
    except (OSError, ValueError) as exc:
        raise GeofixError(f"cannot read exported trials {path}: {exc}") from None
    if ds.attrs.get("geofix_trials") != 1:
        raise GeofixError(f"{path} is not a geofix trials export (no geofix_trials attribute)")
    ins_model = _ins_model_from(ds)
    grid = _grid_from(ds)
    trials = []
    shared = _prior_from(ds, 0, grid) if "prior_z" in ds and ds["prior_z"].ndim == 2 else None
    for k in range(ds.sizes["trial"]):
        trial = _trial_from(ds, k, ins_model)
        if "prior_z" in ds:
            prior = _prior_from(ds, k, grid) if shared is None else shared
            trial = replace(trial, prior_map=prior, prior_shift_m=_shift_from(ds, k))
        count = int(ds.attrs.get("geofix_fields", 0))
        if count:
            trial = replace(trial, fields=tuple(_field_from(ds, k, i) for i in range(1, count + 1)))
        trials.append(trial)
    return grid, trials


def _grid_from(ds) -> Grid:
    return _grid_of(ds.attrs, ds["z"].values)


def _prior_from(ds, k: int, grid: Grid) -> Grid:
    """Trial ``k``'s prior map (kind and units those of the seabed ``grid``)."""
    a = ds.attrs
    values = ds["prior_z"].values
    return Grid(
        values[k] if values.ndim == 3 else values,
        x0=float(a["prior_grid_x0"]),
        y0=float(a["prior_grid_y0"]),
        dx=float(a["prior_grid_dx"]),
        dy=float(a["prior_grid_dy"]),
        kind=grid.kind,
        units=grid.units,
        name=str(a["prior_grid_name"]),
        meta=json.loads(a["prior_grid_meta_json"]),
    )


def _attr_grid(ds, var: str, values) -> Grid:
    return _grid_of(ds[var].attrs, values)


def _grid_of(a, values) -> Grid:
    """A map from ``values`` and the ``grid_*`` attributes ``a`` it was exported with."""
    return Grid(
        values,
        x0=float(a["grid_x0"]),
        y0=float(a["grid_y0"]),
        dx=float(a["grid_dx"]),
        dy=float(a["grid_dy"]),
        kind=str(a["grid_kind"]),
        units=str(a["grid_units"]),
        name=str(a["grid_name"]),
        meta=json.loads(a["grid_meta_json"]),
    )


def _field_from(ds, k: int, i: int) -> TrialField:
    """Trial ``k``'s further field ``i`` (1-based) as exported."""
    name = f"field{i}"
    field_map = _attr_grid(ds, f"{name}_z", ds[f"{name}_z"].values)
    prior, sensed, shift = field_map, None, None
    if f"{name}_prior_z" in ds:
        prior = _attr_grid(ds, f"{name}_prior_z", ds[f"{name}_prior_z"].values[k])
        sensed = field_map
        shift = np.array([float(ds[f"{name}_prior_shift_{a}"].values[k]) for a in ("x", "y")])
    unlagged = f"{name}_unlagged_measured"
    return TrialField(
        kind=field_map.kind,
        sensor=str(ds[f"{name}_z"].attrs["sensor"]),
        measured=ds[f"{name}_measured"].values[k],
        offsets=np.column_stack(
            [ds[f"{name}_offset_across"].values, ds[f"{name}_offset_along"].values]
        ),
        noise_std=float(ds[f"{name}_noise_std"].values[k]),
        beam_noise_std=np.asarray(ds[f"{name}_beam_noise_std"].values[k], dtype=float),
        grid=prior,
        lag_s=float(ds[f"{name}_z"].attrs["lag_s"]),
        unlagged_measured=ds[unlagged].values[k] if unlagged in ds else None,
        sensed=sensed,
        prior_shift_m=shift,
    )


def _shift_from(ds, k: int) -> np.ndarray:
    return np.array([float(ds["prior_shift_x"].values[k]), float(ds["prior_shift_y"].values[k])])


def _trial_from(ds, k: int, ins_model: InsErrorModel | None = None) -> Trial:
    def pair(name: str) -> np.ndarray:
        return np.column_stack([ds[f"{name}_x"].values[k], ds[f"{name}_y"].values[k]])

    return Trial(
        truth=pair("truth"),
        true_heading=ds["true_heading"].values[k],
        indicated=pair("indicated"),
        indicated_heading=ds["indicated_heading"].values[k],
        times=ds["times"].values[k],
        measured=ds["measured"].values[k],
        offsets=np.column_stack([ds["offset_across"].values, ds["offset_along"].values]),
        sigma_position=ds["sigma_position"].values[k],
        leg_starts=tuple(int(s) for s in ds["leg_start"].values),
        noise_std=float(ds["noise_std"].values[k]),
        sensor=str(ds.attrs["sensor"]),
        map_error_std=float(ds["map_error_std"].values[k]),
        index=int(ds["trial_index"].values[k]),
        **_extras_from(ds, k),
        beam_noise_std=_beam_noise_std_from(ds, k),
        ins_model=ins_model,
    )


def _beam_noise_std_from(ds, k: int) -> np.ndarray | None:
    if "beam_noise_std" not in ds:
        return None
    row = np.asarray(ds["beam_noise_std"].values[k], dtype=float)
    return None if np.isnan(row).all() else row


#: Optional trial fields written as ``extra_<key>`` variables (names kept from the format's
#: first version, whose trials held them in a dictionary).
OPTIONAL_FIELDS = ("true_velocity", "dvl_velocity", "unlagged_measured", "lag_s")


def _optional_fields(trial: Trial) -> dict:
    """The optional fields a trial has: every array that is set, and ``lag_s`` with them."""
    out = {}
    for key in OPTIONAL_FIELDS[:3]:
        if getattr(trial, key) is not None:
            out[key] = getattr(trial, key)
    if trial.unlagged_measured is not None:
        out["lag_s"] = trial.lag_s
    return out


def _extras_from(ds, k: int) -> dict:
    """The optional trial fields stored as ``extra_*`` variables (unknown ones are skipped)."""
    extras: dict = {}
    pending: dict = {}
    for var in ds.data_vars.values():
        key = var.attrs.get("extra_key")
        if key is None:
            continue
        component = var.attrs["extra_component"]
        value = var.values[k]
        if component == "scalar":
            extras[key] = float(value)
        elif component in ("x", "y"):
            pending.setdefault(key, {})[component] = value
        else:
            extras[key] = value
    for key, parts in pending.items():
        extras[key] = np.column_stack([parts["x"], parts["y"]])
    return {key: value for key, value in extras.items() if key in OPTIONAL_FIELDS}
