"""What every method consumes and returns: :class:`MatchProblem`, :class:`Fix`, :class:`Matcher`.

Batch matchers (TERCOM, ICCP, GA-SCA, ...) and recursive filters (SITAN, PMF, PF) answer
the same protocol: ``method.match(problem, rng) -> Fix``. A batch matcher is handed one
matching window (one leg); a method whose class attribute ``recursive`` is True is handed
the whole mission at once and returns its estimate at every sample.

A problem may carry further fields measured at the same samples (:class:`MatchField`: a
gravimeter beside the echosounder, say): the recursive filters PMF, PF and MPF weigh them
all; the batch matchers and SITAN use the primary field only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, ClassVar, Protocol, runtime_checkable

import numpy as np

from geofix.errors import ConfigError
from geofix.maps.grid import Grid

if TYPE_CHECKING:
    from geofix.nav.errstate import InsErrorModel


@dataclass(frozen=True, eq=False)
class MatchField:
    """One more field a problem's vehicle measured (a gravimeter beside an echosounder).

    What a recursive filter weighs besides the problem's own (primary) field; the batch
    matchers and SITAN use the primary field only.

    Parameters
    ----------
    grid : Grid
        This field's prior map (same metric frame as the problem's).
    measured : numpy.ndarray
        ``(n, b)`` readings at the problem's samples, this map's units, NaN = missing.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame footprint offsets ``(across, along)``, metres.
    noise_std : float
        1-sigma of the sensor noise, map units (nadir value for a multibeam).
    sensor : str
        The sensor type (``"gravimeter"``, ``"magnetometer"``, ...).
    beam_noise_std : numpy.ndarray or None
        ``(b,)`` 1-sigma of every beam's noise, map units (None: ``noise_std``).
    map_error_std : float
        1-sigma of this map's own error, map units.
    lag_s : float
        The sensor's declared first-order lag time constant, seconds (0: none).
    """

    grid: Grid
    measured: np.ndarray
    offsets: np.ndarray
    noise_std: float = 0.0
    sensor: str = "gravimeter"
    beam_noise_std: np.ndarray | None = None
    map_error_std: float = 0.0
    lag_s: float = 0.0

    def __post_init__(self) -> None:
        lag = float(self.lag_s)
        if not (np.isfinite(lag) and lag >= 0):
            raise ConfigError(f"MatchField: lag_s must be finite and >= 0, got {self.lag_s}")
        beams = np.asarray(self.offsets).shape[0]
        if np.ndim(self.measured) != 2 or np.shape(self.measured)[1] != beams:
            raise ConfigError(
                f"MatchField: measured has shape {np.shape(self.measured)}, expected (n, {beams})"
            )
        if self.beam_noise_std is not None:
            check_beam_noise_std(self.beam_noise_std, beams, "MatchField")

    @property
    def kind(self) -> str:
        """The field's kind, its map's (``depth``, ``gravity``, ``magnetic``)."""
        return self.grid.kind

    def part(self, part: slice) -> MatchField:
        """The same field over samples ``part``."""
        return replace(self, measured=self.measured[part])


@dataclass(frozen=True, eq=False)
class MatchProblem:
    """Everything a matcher may use, nothing else (no truth).

    Parameters
    ----------
    grid : Grid
        The prior map.
    indicated : numpy.ndarray
        ``(n, 2)`` INS-indicated positions, metres.
    heading : numpy.ndarray
        ``(n,)`` INS-indicated heading, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` sensor footprint offsets in the body frame ``(across, along)``, metres;
        one row ``[0, 0]`` for single-beam and gravimeter.
    measured : numpy.ndarray
        ``(n, b)`` measured field values (same units and sign as the map), NaN = missing.
    sigma_position : numpy.ndarray
        ``(n,)`` prior 1-sigma (per axis) of the indicated position error at each sample,
        metres, predicted by the INS error model from the scenario's datasheet numbers.
    times : numpy.ndarray
        ``(n,)`` sample times, seconds.
    noise_std : float
        1-sigma of the sensor noise, in map units (as declared by the scenario; the nadir
        value for a multibeam, whose noise grows towards the swath edges).
    sensor : str
        ``"singlebeam"``, ``"multibeam"`` or ``"gravimeter"``.
    map_error_std : float
        1-sigma of the map's own error, map units (added to the sensor noise by methods
        that weigh measurements).
    beam_noise_std : numpy.ndarray or None
        ``(b,)`` 1-sigma of the sensor noise of every beam, map units; None means
        ``noise_std`` for every beam. Methods that weigh beams use :meth:`beam_noise_var`.
    dvl_velocity : numpy.ndarray or None
        ``(n, 2)`` DVL velocity over ground in the local frame, m/s, when the vehicle has
        one (aiding data a method may use).
    ins_model : InsErrorModel or None
        The INS error model of the navigator (:mod:`geofix.nav.errstate`), for the
        error-state filters; None when unknown.
    lag_s : float
        The sensor's declared first-order lag time constant, seconds (a gravimeter's
        datasheet number; 0 = no lag). The recursive filters undo it before their update
        (:func:`geofix.measurement.lag_compensated`); ``measured`` stays as recorded.
    fields : tuple of MatchField
        The other fields measured at the same samples, each with its own map, readings
        and noise (``()``: the one field above). The recursive filters PMF, PF and MPF
        weigh them all (the product of the fields' likelihoods); the batch matchers and
        SITAN use the primary field above only.
    """

    grid: Grid
    indicated: np.ndarray
    heading: np.ndarray
    offsets: np.ndarray
    measured: np.ndarray
    sigma_position: np.ndarray
    times: np.ndarray
    noise_std: float = 0.0
    sensor: str = "singlebeam"
    map_error_std: float = 0.0
    beam_noise_std: np.ndarray | None = None
    dvl_velocity: np.ndarray | None = None
    ins_model: InsErrorModel | None = None
    lag_s: float = 0.0
    fields: tuple[MatchField, ...] = ()

    def __post_init__(self) -> None:
        lag = float(self.lag_s)
        if not (np.isfinite(lag) and lag >= 0):
            raise ConfigError(f"MatchProblem: lag_s must be finite and >= 0, got {self.lag_s}")
        for extra in self.fields:
            if np.shape(extra.measured)[0] != np.shape(self.indicated)[0]:
                raise ConfigError(
                    f"MatchProblem: a {extra.kind} field has {np.shape(extra.measured)[0]} "
                    f"samples, the problem {np.shape(self.indicated)[0]}"
                )

    @property
    def n(self) -> int:
        """Number of samples."""
        return self.indicated.shape[0]

    @property
    def beams(self) -> int:
        """Number of beams ``b``."""
        return self.offsets.shape[0]

    def beam_noise_var(self) -> np.ndarray:
        """Measurement variance of every beam: sensor noise plus map error.

        Returns
        -------
        numpy.ndarray
            ``(b,)`` ``beam_noise_std^2 + map_error_std^2`` (``noise_std`` for every beam
            when ``beam_noise_std`` is None), map units squared.

        Raises
        ------
        ConfigError
            ``beam_noise_std`` is not ``(b,)`` finite values >= 0 (a problem whose beams
            were subset without subsetting ``beam_noise_std``, say).
        """
        if self.beam_noise_std is None:
            std = np.full(self.beams, float(self.noise_std))
        else:
            check_beam_noise_std(self.beam_noise_std, self.beams, "MatchProblem")
            std = np.asarray(self.beam_noise_std, dtype=float)
        return std**2 + float(self.map_error_std) ** 2

    def nadir(self) -> MatchProblem:
        """The same problem reduced to the beam nearest nadir (smallest ``|across|``).

        Returns
        -------
        MatchProblem
            ``offsets`` ``(1, 2)`` metres, ``measured`` ``(n, 1)`` and ``beam_noise_std``
            ``(1,)`` (when given) of that beam; ``self`` for a single beam.
        """
        if self.beams == 1:
            return self
        k = int(np.argmin(np.abs(self.offsets[:, 0])))
        noise = self.beam_noise_std
        return replace(
            self,
            offsets=self.offsets[k : k + 1],
            measured=self.measured[:, k : k + 1],
            beam_noise_std=None if noise is None else np.asarray(noise, float)[k : k + 1],
        )

    def footprint(self, track: np.ndarray, heading: np.ndarray | None = None) -> tuple:
        """Map positions of every beam for a track.

        Parameters
        ----------
        track : numpy.ndarray
            ``(..., n, 2)`` vehicle positions, metres.
        heading : numpy.ndarray, optional
            ``(..., n)`` headings, radians; the indicated heading by default.

        Returns
        -------
        tuple of numpy.ndarray
            ``(x, y)`` each of shape ``(..., n, b)``, metres.
        """
        psi = self.heading if heading is None else heading
        return footprint_xy(track, psi, self.offsets)


def registered_covariance(grid: Grid, covariance):
    """A position covariance matched on ``grid`` plus the map's stated registration.

    Parameters
    ----------
    grid : Grid
        The prior map (its :attr:`~geofix.maps.grid.Grid.registration_var`; for a fused
        problem the primary field's map).
    covariance : numpy.ndarray or None
        ``(..., 2, 2)`` covariances in the map's frame, m^2.

    Returns
    -------
    numpy.ndarray or None
        ``covariance + registration_var * I`` (the same array when the map states no
        registration; None for None).
    """
    if covariance is None:
        return None
    var = grid.registration_var
    if var == 0.0:
        return covariance
    return np.asarray(covariance, dtype=float) + var * np.eye(2)


def check_beam_noise_std(beam_noise_std, beams: int, who: str) -> None:
    """Raise unless ``beam_noise_std`` is ``(beams,)`` finite values >= 0 (map units).

    Parameters
    ----------
    beam_noise_std : array_like
        Per-beam measurement noise standard deviations, map units.
    beams : int
        Expected number of beams.
    who : str
        Name of the caller, first word of the error message.

    Raises
    ------
    ConfigError
        Wrong shape, a negative or a non-finite value.
    """
    std = np.asarray(beam_noise_std, dtype=float)
    if std.shape != (beams,):
        raise ConfigError(f"{who}: beam_noise_std has shape {std.shape}, expected ({beams},)")
    if not (np.isfinite(std).all() and (std >= 0).all()):
        raise ConfigError(f"{who}: beam_noise_std must be finite and >= 0")


def footprint_xy(track: np.ndarray, heading: np.ndarray, offsets: np.ndarray) -> tuple:
    """Beam positions ``(x, y)`` of shape ``(..., n, b)`` for vehicle ``track`` ``(..., n, 2)``.

    Parameters
    ----------
    track : numpy.ndarray
        ``(..., n, 2)`` vehicle positions ``(x east, y north)``, metres.
    heading : numpy.ndarray
        ``(..., n)`` headings, radians clockwise from north.
    offsets : numpy.ndarray
        ``(b, 2)`` body-frame beam offsets ``(across, along)``, metres (across positive to
        starboard).

    Returns
    -------
    tuple of numpy.ndarray
        ``(x, y)`` each of shape ``(..., n, b)``, metres.
    """
    track = np.asarray(track, dtype=float)
    s = np.sin(heading)[..., None]
    c = np.cos(heading)[..., None]
    across = offsets[:, 0]
    along = offsets[:, 1]
    # starboard unit vector is (cos psi, -sin psi); forward is (sin psi, cos psi)
    x = track[..., 0:1] + across * c + along * s
    y = track[..., 1:2] - across * s + along * c
    return x, y


@dataclass(frozen=True, eq=False)
class Fix:
    """A method's answer for one problem.

    Parameters
    ----------
    track : numpy.ndarray
        ``(n, 2)`` estimated positions, metres.
    covariance : numpy.ndarray or None
        ``(2, 2)`` covariance of the last position, m^2, when the method can tell.
    cost : float
        The method's own final cost (lower is better), for diagnostics.
    evaluations : int
        Map look-ups or candidate scores spent, for cost comparisons.
    ambiguous : bool
        The method's own integrity flag: True when it cannot tell the fix from another.
    diagnostics : dict
        Anything else worth keeping (iterations, per-step covariances ``(n, 2, 2)``, ...).
    """

    track: np.ndarray
    covariance: np.ndarray | None = None
    cost: float = float("nan")
    evaluations: int = 0
    ambiguous: bool = False
    diagnostics: dict = field(default_factory=dict)


@runtime_checkable
class Matcher(Protocol):
    """A positioning method. Its constructor only stores settings (with defaults)."""

    name: ClassVar[str]
    recursive: ClassVar[bool]

    def match(self, problem: MatchProblem, rng: np.random.Generator) -> Fix:
        """Solve ``problem``; ``rng`` is the only source of randomness."""
        ...
