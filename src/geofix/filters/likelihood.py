"""The terrain measurement model of the grid and particle filters, as one component.

:class:`TerrainLikelihood` holds the measurement-model choices a filter makes beyond the
observation itself: whether the likelihood is flattened by the field's variance within
one hypothesis's share of the area (``discretisation_noise``), and whether that variance
is one for the whole set or each hypothesis's own (``field_variance``). Its methods give
the log-likelihood of a ping at a set of particles (:meth:`TerrainLikelihood.particles`)
or at the nodes of a point-mass grid (:meth:`TerrainLikelihood.nodes`); a hypothesis
offset (:class:`~geofix.filters.hypothesis_offset.HypothesisOffset`), when the filter
carries one, is marginalised over.

- **global** field variance, particles: the field's change over a particle's share ``h``
  along x and y at a subset of the particles, ``(mean(d_x^2) + mean(d_y^2)) / 12``
  (:func:`spread_field_variance`), added to every beam's variance; nodes: the same from
  the differences between neighbouring nodes (:func:`node_field_variance`);
- **local**: each hypothesis's own change over its share at its own beams, as one offset
  common to the beams (:func:`~geofix.measurement.local_field_log_likelihood`), while the
  share is at most :data:`LOCAL_MAX_SPACING_CELLS` map cells across.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geofix._measurement_kernels import node_field_variance_kernel
from geofix.errors import ConfigError
from geofix.filters import _grid_ops as ops
from geofix.filters.base import Observation
from geofix.filters.hypothesis_offset import HypothesisOffset
from geofix.filters.offset_sums import ResidualSums
from geofix.maps.grid import Grid
from geofix.measurement import (
    hypotheses_log_likelihood,
    local_field_log_likelihood,
    local_field_reads,
    log_likelihood,
    node_grid_local_log_likelihood,
    node_grid_log_likelihood,
    predict_measurements,
    shift_field_variance,
)

if TYPE_CHECKING:
    from geofix.filters.pmf import PmfState

FIELD_VARIANCES = ("local", "global")
"""The discretisation-noise models of the filters (``field_variance``)."""


LOCAL_MAX_SPACING_CELLS = 1.0
"""Largest share side, map cells, at which ``field_variance=local`` is used; a coarser set
falls back to the global variance. Within one map cell the bilinear field is linear along
each axis, so its change over a side describes the field across the share; over several
cells it does not (on rough terrain the beams' variations within a share ten cells wide
are nearly independent, the global model's assumption, and the local slope misleads)."""

FIELD_VARIANCE_SUBSET = 2000
"""Most particles used to estimate the field's variance within one particle's share."""

FIELD_VARIANCE_DIFFERENCES = FIELD_VARIANCE_SUBSET * 64
"""Most particle-beam differences per axis in that estimate: with more than 64 measured
beams, fewer particles (never below :data:`FIELD_VARIANCE_MIN_PARTICLES`)."""

FIELD_VARIANCE_MIN_PARTICLES = 64
"""Fewest particles used in that estimate (when the set has that many)."""


def check_field_variance(name: str, value: str) -> None:
    """Raise :class:`ConfigError` unless ``value`` is one of :data:`FIELD_VARIANCES`."""
    if value not in FIELD_VARIANCES:
        raise ConfigError(f"{name}: field_variance must be local or global, got {value!r}")


def check_student_dof(name: str, value) -> None:
    """Raise :class:`ConfigError` unless ``value`` is None or a finite number above 0.

    Parameters
    ----------
    name : str
        The filter's name, for the message.
    value : object
        The ``student_dof`` setting.
    """
    if value is None:
        return
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not (ok and np.isfinite(value) and value > 0):
        raise ConfigError(
            f"{name}: student_dof must be a finite number above 0 (unset: the Gaussian), "
            f"got {value!r}"
        )


@dataclass(frozen=True)
class TerrainLikelihood:
    """The terrain (or gravity) measurement model of a grid or particle filter.

    Parameters
    ----------
    discretisation_noise : bool
        Flatten the likelihood by the field's variance within one hypothesis's share of
        the area (none for a dense set, share 0).
    field_variance : str
        ``global``: one field variance for every hypothesis; ``local``: each hypothesis's
        own, common to its beams (:data:`FIELD_VARIANCES`).
    dof : float
        Degrees of freedom of a Student-t likelihood per ping
        (:func:`geofix.measurement.student_t`, the filters' ``student_dof``); inf: the
        Gaussian. A hypothesis's offsets still take the Gaussian Kalman step.
    """

    discretisation_noise: bool = True
    field_variance: str = "global"
    dof: float = np.inf

    def uses_local_field(self, side: float, cell: float) -> bool:
        """Whether a share of ``side`` metres on a map of ``cell`` metres takes the local variance.

        ``discretisation_noise``, ``field_variance=local`` and
        ``0 < side <= LOCAL_MAX_SPACING_CELLS * cell``.
        """
        return self.discretisation_noise and self._local_share(side, cell)

    def _local_share(self, side: float, cell: float) -> bool:
        return self.field_variance == "local" and 0 < side <= LOCAL_MAX_SPACING_CELLS * cell

    def particles(
        self,
        grid: Grid,
        obs: Observation,
        positions: np.ndarray,
        spacing: float,
        cell: float,
        offset: HypothesisOffset | None,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """``(M,)`` measurement log-likelihood of particles, discretisation noise in.

        Parameters
        ----------
        grid : Grid
            The prior map.
        obs : Observation
            The ping (beam offsets, metres; values and variances, map units).
        positions : numpy.ndarray
            ``(M, 2)`` absolute particle positions, metres.
        spacing : float
            Side of one particle's square share ``h``, metres (0: a dense set, no noise).
        cell : float
            Map cell size, metres.
        offset : HypothesisOffset or None
            Each particle's common offset ``N(b_i, P)``, marginalised over.
        rng : numpy.random.Generator
            Draws the particles of the global field variance (:func:`spread_field_variance`).

        Returns
        -------
        numpy.ndarray
            ``(M,)`` log-likelihoods, nats.
        """
        var = obs.noise_var  # a float or a read-only (b,) array: never changed in place
        args = (obs.heading, obs.offsets, obs.values)
        modes = obs.map_modes
        local = self.discretisation_noise and spacing > 0 and self._local_share(spacing, cell)
        if self.discretisation_noise and spacing > 0 and not local:
            var = var + spread_field_variance(grid, positions, spacing, obs, rng)
        sides = spacing * np.eye(2)
        dof = self.dof
        if offset is None:
            if local:
                return local_field_log_likelihood(
                    grid, positions, *args, var, sides, obs.bias_var, None, modes, dof
                )
            return hypotheses_log_likelihood(
                grid, positions, *args, var, obs.bias_var, None, modes, dof
            )
        # each particle's own offsets, N(b_ik, P_k): the map read once for every rate
        if not local:
            predicted = predict_measurements(grid, positions, obs.heading, obs.offsets)
            sums = ResidualSums.of(predicted, obs.values, var, modes)
        else:
            f0, own, shape = local_field_reads(grid, positions, obs.heading, obs.offsets, sides)
            sums = ResidualSums.of(f0.reshape(*shape, -1), obs.values, var, modes, own)
        return offset.marginal(self._given(sums))

    def nodes(
        self, grid: Grid, obs: Observation, state: PmfState
    ) -> tuple[np.ndarray, HypothesisOffset | None]:
        """``(N0, N1)`` measurement log-likelihood of a point-mass grid's nodes.

        With the state's hypothesis offsets the likelihood is marginalised over each
        node's own ``N(b_i, P)`` and the offsets are updated with the same map reads;
        otherwise one compiled pass over nodes and beams where it covers the case (no
        common offset, bilinear map), the prediction arrays elsewhere.

        Parameters
        ----------
        grid : Grid
            The prior map.
        obs : Observation
            The ping (beam offsets, m; values and variances, map units).
        state : PmfState
            The point-mass posterior (its grid, cell and offsets).

        Returns
        -------
        tuple
            The log-likelihoods (nats) and the updated offsets (None without any).
        """
        local = self.uses_local_field(state.spacing.max(), state.cell)
        if state.offset is not None:
            return self._nodes_with_offsets(grid, obs, state, state.offset, local)
        if local:
            return self._nodes_local(grid, obs, state), None
        fused = obs.bias_var == 0 and obs.map_modes is None and grid.interpolation == "bilinear"
        if not (fused and np.isinf(self.dof)):
            return self._nodes_reference(grid, obs, state), None
        # One compiled pass over nodes x beams (the reference path -- node_positions,
        # predict_measurements, node_field_variance, log_likelihood -- to ~1e-15 relative).
        u, v = state.node_offsets
        ll, _ = node_grid_log_likelihood(
            grid,
            (state.centre, state.axes, u, v),
            obs.heading,
            obs.offsets,
            obs.values,
            obs.noise_var,
            self.discretisation_noise,
        )
        return ll, None

    def _nodes_local(self, grid: Grid, obs: Observation, state: PmfState) -> np.ndarray:
        """Every node with its own field variation within its cell.

        One compiled pass over the nodes (one more row and column read for the last
        nodes' differences); through the prediction arrays with a common offset or a map
        read other than bilinear.
        """
        plain = obs.bias_var == 0 and obs.map_modes is None and grid.interpolation == "bilinear"
        if plain and np.isinf(self.dof):
            u, v = state.node_offsets
            frame = (state.centre, state.axes, u, v)
            args = (obs.heading, obs.offsets, obs.values, obs.noise_var)
            return node_grid_local_log_likelihood(grid, frame, state.spacing, *args)
        xy = ops.node_positions(*state.frame, state.shape)
        sides = (state.axes * state.spacing).T  # rows: one node step along each grid axis
        return local_field_log_likelihood(
            grid,
            xy,
            obs.heading,
            obs.offsets,
            obs.values,
            obs.noise_var,
            sides,
            obs.bias_var,
            modes=obs.map_modes,
            dof=self.dof,
        )

    def _nodes_with_offsets(
        self, grid: Grid, obs: Observation, state: PmfState, offset: HypothesisOffset, local
    ) -> tuple[np.ndarray, HypothesisOffset]:
        """Marginalised over each node's own offsets ``N(b_ik, P_k)``, then their update.

        The nodes' predictions are read once for both (the local field variance reads its
        own, with the nodes' sides).
        """
        xy = ops.node_positions(*state.frame, state.shape)
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        if local:  # the map read once: each rate's likelihood from the ping's sums
            sides = (state.axes * state.spacing).T
            _, own, _ = local_field_reads(grid, xy, obs.heading, obs.offsets, sides, predicted)
            sums = ResidualSums.of(predicted, obs.values, obs.noise_var, obs.map_modes, own)
            updated = offset.updated(grid, xy, obs, predicted, sums)
            return offset.marginal(self._given(sums)), updated
        updated = offset.updated(grid, xy, obs, predicted)

        def given(bias_var, shift) -> np.ndarray:
            shifted = predicted + shift[..., None]
            var = obs.noise_var
            if self.discretisation_noise:
                var = var + node_field_variance(shifted, obs.values)
            return log_likelihood(shifted, obs.values, var, bias_var, obs.map_modes, self.dof)

        return offset.marginal(given), updated

    def _given(self, sums: ResidualSums):
        """``(var, mean) -> log-likelihoods`` of the ping's sums, with this model's ``dof``."""
        if np.isinf(self.dof):
            return sums.log_likelihood
        return lambda bias_var, shift: sums.log_likelihood(bias_var, shift, self.dof)

    def _nodes_reference(self, grid: Grid, obs: Observation, state: PmfState) -> np.ndarray:
        """Through the prediction array: a common offset, or a map read other than bilinear."""
        xy = ops.node_positions(*state.frame, state.shape)
        predicted = predict_measurements(grid, xy, obs.heading, obs.offsets)
        var = obs.noise_var  # a float or a read-only (b,) array: never changed in place
        if self.discretisation_noise:
            var = var + node_field_variance(predicted, obs.values)
        return log_likelihood(predicted, obs.values, var, obs.bias_var, obs.map_modes, self.dof)


def field_variance_particles(particles: int, beams: int) -> int:
    """Particles drawn for the field variance of ``beams`` measured beams.

    ``min(particles, FIELD_VARIANCE_SUBSET)`` up to 64 beams; beyond, as many as keep
    ``particles x beams`` near :data:`FIELD_VARIANCE_DIFFERENCES` (an all-beam multibeam
    ping averages over hundreds of beams per particle already), but at least
    :data:`FIELD_VARIANCE_MIN_PARTICLES`.
    """
    by_reads = max(FIELD_VARIANCE_MIN_PARTICLES, FIELD_VARIANCE_DIFFERENCES // max(beams, 1))
    return min(particles, FIELD_VARIANCE_SUBSET, by_reads)


def spread_field_variance(
    grid: Grid, positions: np.ndarray, spacing: float, obs: Observation, rng
) -> float:
    """Field variance within a square of side ``spacing``, map units squared.

    ``(mean(d_x^2) + mean(d_y^2)) / 12`` over the measured beams, ``d_x``, ``d_y`` the
    change of the field read by each beam when the vehicle moves by ``spacing`` along x
    and along y, at :func:`field_variance_particles` particles drawn with ``rng`` (the
    point-mass filter's node-field variance with particles for nodes); 0 when no
    difference is finite.

    Parameters
    ----------
    grid : Grid
        The prior map.
    positions : numpy.ndarray
        ``(M, 2)`` absolute particle positions, metres.
    spacing : float
        Side of one particle's share, metres.
    obs : Observation
        The ping.
    rng : numpy.random.Generator
        Draws the particles used.
    """
    use = np.isfinite(obs.values)
    m = positions.shape[0]
    pick = rng.choice(m, field_variance_particles(m, int(use.sum())), replace=False)
    return shift_field_variance(
        grid, positions[pick], obs.heading, obs.offsets, obs.values, spacing
    )


def node_field_variance(predicted: np.ndarray, measured: np.ndarray) -> float:
    """Variance of the field within one grid node, map units squared.

    Parameters
    ----------
    predicted : numpy.ndarray
        ``(N0, N1, b)`` field each beam reads from each node (NaN off the map).
    measured : numpy.ndarray
        ``(b,)`` measurement; only the beams it holds count.

    Returns
    -------
    float
        ``(mean(d0^2) + mean(d1^2)) / 12`` with ``d0``, ``d1`` the field differences between
        neighbouring nodes along each grid axis (a position uniform over one node's cell);
        0 when no difference is finite.
    """
    return node_field_variance_kernel(predicted, measured)  # one compiled pass


__all__ = [
    "FIELD_VARIANCES",
    "LOCAL_MAX_SPACING_CELLS",
    "TerrainLikelihood",
    "check_field_variance",
    "field_variance_particles",
    "node_field_variance",
    "spread_field_variance",
]
