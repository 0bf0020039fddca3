"""The recursive side of geofix: one loop, pure ``predict`` / ``update`` steps.

A recursive filter (SITAN, the SITAN bank, the point-mass filter, the particle filter)
keeps its state in a small immutable value and exposes pure functions:

- ``initialize(problem, rng) -> state`` -- the prior at the first sample,
- ``predict(state, motion, rng) -> state`` -- apply the INS motion between two samples,
- ``update(state, observation, grid, rng) -> state`` -- fold in one sample's measurement,
- ``estimate(state) -> (position (2,), covariance (2, 2))`` -- absolute position, metres,
- ``is_ambiguous(state) -> bool`` -- the filter's own integrity flag (optional).

:func:`run_filter` owns the time loop; :class:`RecursiveFilter` gives every filter the
``match(problem, rng) -> Fix`` of the matcher protocol with ``recursive = True``, so a
filter runs through the same campaign runner as a batch matcher and is handed the whole
mission at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from threadpoolctl import threadpool_limits

from geofix.filters.loop import FilterSettings, FilterStepper
from geofix.filters.state import state_mode
from geofix.maps.grid import Grid
from geofix.measurement import lag_compensated
from geofix.problem import Fix, MatchProblem, registered_covariance


@dataclass(frozen=True)
class Motion:
    """INS motion between samples ``k - 1`` and ``k``.

    Parameters
    ----------
    displacement : numpy.ndarray
        ``(2,)`` indicated (INS) displacement over the step, metres.
    dt : float
        Step duration, seconds.
    process_var : float
        Per-axis variance the INS position error gains over the step, m^2 (from the
        growth of the prior sigma of the problem; at least ``1e-6``).
    """

    displacement: np.ndarray
    dt: float
    process_var: float


@dataclass(frozen=True)
class Observation:
    """One sample's measurement and geometry.

    Parameters
    ----------
    values : numpy.ndarray
        ``(b,)`` measured field values, NaN = missing.
    indicated : numpy.ndarray
        ``(2,)`` indicated position at the sample, metres.
    heading : float
        Indicated heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets, metres.
    noise_var : numpy.ndarray or float
        Measurement variance, sensor noise plus map error, map units squared: ``(b,)``
        per beam (a multibeam's outer beams are noisier than nadir; read-only when built
        by :func:`observations`), or one float for every beam when the problem declares
        no per-beam noise. The measurement functions accept both.
        The values are the readings with the sensor's declared lag undone
        (:func:`geofix.measurement.lag_compensated`).
    index : int
        Sample index.
    bias_var : float
        Variance of an unknown offset common to every beam (tide, sound speed, map
        datum), map units squared, the likelihood is marginalised over; 0: none. A
        filter that carries the offset per hypothesis
        (:mod:`geofix.filters.hypothesis_offset`) takes it as the offset's prior variance
        at its first ping.
    bias_walk : float
        Variance the offset gains per second, map units squared per second (a filter
        that carries the offset per hypothesis).
    bias_per_hypothesis : bool
        The filter is to carry the offset per hypothesis from this ping on (``bias_var``
        its prior variance); False: ``bias_var`` is marginalised around the values as
        given.
    bias_fast_walk : float
        A second, faster walk rate the per-hypothesis offset weighs unless the filter's
        ``fast_offset_walk`` says otherwise, as a factor on ``bias_walk`` (0: the declared
        rate alone; :func:`geofix.filters.nuisance.default_fast_offset_walk`).
    bias_smooth_m : float
        The length scale of a smooth offset the per-hypothesis offset weighs beside its
        walks unless the filter's ``offset_smooth_m`` says otherwise, metres along the
        track (0: none; :func:`geofix.filters.nuisance.default_offset_smooth`).
    map_modes : numpy.ndarray or None
        ``(b, k)`` shapes of the map's error across the ping's beams (a tilt and a
        curvature across a swath), each column a shape times its 1-sigma, map units: the
        likelihood is marginalised over them beside the offset
        (:class:`geofix.filters.nuisance.SwathModes`). None: none.
    """

    values: np.ndarray
    indicated: np.ndarray
    heading: float
    offsets: np.ndarray
    noise_var: np.ndarray | float
    index: int
    bias_var: float = 0.0
    bias_walk: float = 0.0
    bias_per_hypothesis: bool = False
    bias_fast_walk: float = 0.0
    bias_smooth_m: float = 0.0
    map_modes: np.ndarray | None = None


class RecursiveFilter:
    """Mixin for filter dataclasses: the matcher protocol on top of :func:`run_filter`.

    It also declares what a filter says of itself to the loop that steps it
    (:class:`geofix.filters.loop.FilterStepper`) and to the online navigator, with the
    defaults a filter keeps unless it declares otherwise (as a class attribute, a
    dataclass field or a property):

    - ``name``: the registered method name (``"pmf"``, ``"sitan"``, ...);
    - ``recursive``: True, the filter runs sample by sample;
    - ``needs_ins_model``: False; True for a filter on the INS error state, which needs
      an INS error model to start (``mpf``, ``pmf:model=errstate``);
    - ``map_model``: ``"exact"``, what the likelihood assumes of the prior map
      (:mod:`geofix.filters.nuisance`; ``pmf``, ``pf`` and ``mpf`` take it as a
      setting);
    - ``carries_offset``: False; True when each point of the state carries its own
      common offset (``map_model=imperfect``);
    - ``fuses_fields``: False; True for a filter that weighs further fields beside the
      primary one (``pmf``, ``pf``, ``mpf``);
    - ``mode(state)``: the state's mode.
    """

    name: ClassVar[str]
    recursive: ClassVar[bool] = True
    fuses_fields: ClassVar[bool] = False
    map_model: str = "exact"

    def mode(self, state) -> np.ndarray:
        """The position ``(2,)`` the filter reports as its most likely one, metres.

        The state's mode (:func:`geofix.filters.state.state_mode`); a filter may report
        another (:meth:`geofix.filters.mpf.Mpf.mode`: the weighted mean).
        """
        return state_mode(self, state)

    @property
    def needs_ins_model(self) -> bool:
        """The filter needs an INS error model to start (default: no)."""
        return False

    @property
    def carries_offset(self) -> bool:
        """Each point of the state carries its own common offset (default: no)."""
        return False

    def match(self, problem: MatchProblem, rng: np.random.Generator) -> Fix:
        """Run the filter over the whole problem and return its estimate at every sample.

        BLAS runs on one thread: the filters' products are small or tall and thin (a
        hypothesis's few columns against its beams, ``M x d`` by ``d x d``), where threads
        gain nothing and a multi-threaded BLAS on a busy machine (a campaign's other
        processes) makes them several times slower.
        """
        with threadpool_limits(limits=1, user_api="blas"):
            return run_filter(self, problem, rng)

    def is_ambiguous(self, state) -> bool:
        """Integrity flag of a state (default: never)."""
        return False

    def offset_moments(self, state) -> tuple[float, float] | None:
        """Mean and variance of the points' own offsets, map units (default: none carried)."""
        return None


def motions(problem: MatchProblem) -> list[Motion]:
    """INS motion of every step ``k = 1 .. n-1`` (index 0 of the list is step 1)."""
    disp = np.diff(problem.indicated, axis=0)
    dts = np.diff(problem.times)
    var = np.maximum(np.diff(np.asarray(problem.sigma_position, float) ** 2), 1e-6)
    return [Motion(d, float(t), float(v)) for d, t, v in zip(disp, dts, var, strict=True)]


def observations(problem: MatchProblem) -> list[Observation]:
    """The measurement of every sample, with the variance of sensor plus map error.

    ``noise_var`` (map units squared, floored at ``1e-12``) is
    :meth:`MatchProblem.beam_noise_var`, one read-only ``(b,)`` array shared by all
    observations, when the problem has ``beam_noise_std``; otherwise the float
    ``noise_std^2 + map_error_std^2`` (the same for every beam). ``values`` are the
    readings with the declared lag ``problem.lag_s`` undone (causally:
    :func:`geofix.measurement.lag_compensated`), the one place every recursive filter
    (PMF, PF, MPF, SITAN) gets its readings from.
    """
    if problem.beam_noise_std is None:
        noise_var = max(problem.noise_std**2 + problem.map_error_std**2, 1e-12)
    else:
        noise_var = np.maximum(problem.beam_noise_var(), 1e-12)
        noise_var.setflags(write=False)
    measured = lag_compensated(problem)
    return [
        Observation(
            values=measured[k],
            indicated=problem.indicated[k],
            heading=float(problem.heading[k]),
            offsets=problem.offsets,
            noise_var=noise_var,
            index=k,
        )
        for k in range(problem.n)
    ]


def run_filter(filt, problem: MatchProblem, rng: np.random.Generator) -> Fix:
    """The one time loop: initialise, then predict and update at every sample.

    Every step goes through :class:`geofix.filters.loop.FilterStepper` (the filter with
    its measurement model's nuisance states), the same steps the online navigator
    (:mod:`geofix.navigator`) drives with its gating and re-initialisation around them.

    Parameters
    ----------
    filt : RecursiveFilter
        The filter.
    problem : MatchProblem
        The mission: its prior at the first sample, the motions and the pings.
    rng : numpy.random.Generator
        Source of every random draw of the filter.

    Returns
    -------
    Fix
        ``track`` the estimate at every sample; ``covariance`` the last one;
        ``diagnostics["covariances"]`` ``(n, 2, 2)``, each with the map's stated
        registration (:func:`geofix.problem.registered_covariance`); ``ambiguous`` from
        the final state.
    """
    grid: Grid = problem.grid
    obs = observations(problem)
    steps = motions(problem)
    stepper = FilterStepper(filt, grid, FilterSettings(), rng)
    stepper.start(problem)
    means, covs = [np.empty((problem.n, 2)), np.empty((problem.n, 2, 2))]
    for k in range(problem.n):
        if k > 0:
            stepper.predict(steps[k - 1])
        means[k], covs[k] = stepper.update(obs[k], float(problem.times[k]))
    state = stepper.state
    covs = registered_covariance(grid, covs)
    return Fix(
        track=means,
        covariance=covs[-1],
        cost=float("nan"),
        evaluations=int(state.evaluations),
        ambiguous=bool(filt.is_ambiguous(state)),
        diagnostics={"covariances": covs},
    )
