r"""A ping's residual sums, read once, for every offset a hypothesis may carry.

A filter whose hypotheses carry their own common offset (:mod:`.hypothesis_offset`)
weighs each ping once per offset rate: the hypothesis's residuals ``d = y - h(x)``
shifted by its offset mean ``b`` under that rate's variance ``P``. Every such
likelihood, and the offsets' own Kalman step, depends on the shifted residuals only
through a few sums over the beams that the shift enters linearly. With ``w_b`` each
valid beam's inverse variance (0 off the map or for a missing beam) and ``M`` the
columns of a map error's shapes across the swath:

- ``S = sum w``, ``A = sum w d``, ``Q = sum w d^2``;
- ``m1 = M^T W 1``, ``md = M^T W d`` and ``G = M^T W M``;

then ``r = d - b`` has ``sum w r = A - b S``, ``sum w r^2 = Q - 2 b A + b^2 S`` and
``M^T W r = md - b m1``. The sums are formed once per ping (one pass over hypotheses
and beams); each rate's likelihood is then a few operations per hypothesis, the same
value as :func:`geofix.measurement.log_likelihood` on the shifted predictions (to
rounding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geofix.filters._spd_kernels import quadratic_and_logdet
from geofix.measurement import OFF_MAP_LOG_LIKELIHOOD, student_t, weighted_gram


@dataclass(frozen=True)
class ResidualSums:
    """The sums over one ping's beams of every hypothesis's residuals.

    Attributes
    ----------
    weight : numpy.ndarray
        ``(m,)`` ``S``, the valid beams' summed inverse variance (map units^-2).
    linear : numpy.ndarray
        ``(m,)`` ``A``, the inverse-variance-weighted sum of residuals (map units^-1).
    square : numpy.ndarray
        ``(m,)`` ``Q``, the weighted sum of squared residuals (dimensionless).
    off_map : numpy.ndarray
        ``(m,)`` beams measured but predicted off the map.
    shape : tuple
        The hypotheses' shape (``m`` is its product).
    mode_weight, mode_linear : numpy.ndarray or None
        ``(m, c)`` ``M^T W 1`` (map units^-1) and ``M^T W d`` (dimensionless) of the map
        error's shape columns (None without any).
    mode_gram : numpy.ndarray or None
        ``(m, c, c)`` ``M^T W M`` (dimensionless).
    count : numpy.ndarray or None
        ``(m,)`` valid beams of each hypothesis (a Student-t likelihood's ``n``).
    """

    weight: np.ndarray
    linear: np.ndarray
    square: np.ndarray
    off_map: np.ndarray
    shape: tuple
    mode_weight: np.ndarray | None = None
    mode_linear: np.ndarray | None = None
    mode_gram: np.ndarray | None = None
    count: np.ndarray | None = None

    @classmethod
    def of(cls, predicted, measured, noise_var, modes=None, own=None) -> ResidualSums:
        """The sums of every hypothesis's residuals.

        Parameters
        ----------
        predicted : numpy.ndarray
            ``(..., b)`` predicted values (NaN off the map), map units.
        measured : numpy.ndarray
            ``(b,)`` measured values (NaN = missing beam), map units.
        noise_var : float or numpy.ndarray
            Per-beam variance, scalar, ``(b,)`` or per hypothesis ``(..., b)``, map
            units squared; it must not depend on the offset.
        modes : numpy.ndarray, optional
            ``(b, c)`` shapes of a map error across the beams times their 1-sigma, map
            units.
        own : numpy.ndarray, optional
            ``(m, b, c')`` columns of each of the ``m`` flattened hypotheses (its field's
            change within its share, :func:`geofix.measurement.local_field_reads`), map
            units: marginalised over beside ``modes``, as
            :func:`geofix.measurement.local_field_from_reads` does.
        """
        measured = np.asarray(measured, dtype=float)
        predicted = np.asarray(predicted, dtype=float)
        beams = measured.shape[0]
        residual = measured - predicted.reshape(-1, beams)
        valid = np.isfinite(residual)
        inv_var = 1.0 / np.asarray(noise_var, dtype=float)
        if inv_var.ndim > 1:
            inv_var = inv_var.reshape(-1, beams)
        w = np.where(valid, inv_var, 0.0)
        d = np.where(valid, residual, 0.0)
        wd = w * d
        sums = {
            "weight": w.sum(axis=-1),
            "linear": wd.sum(axis=-1),
            "square": np.einsum("mb,mb->m", wd, d),
            "off_map": (~valid & np.isfinite(measured)).sum(axis=-1),
            "count": valid.sum(axis=-1),
            "shape": predicted.shape[:-1],
        }
        if own is not None:
            sums.update(_own_sums(w, wd, np.asarray(own, dtype=float), modes, beams))
        elif modes is not None:
            modes = np.asarray(modes, dtype=float).reshape(beams, -1)
            sums["mode_weight"] = w @ modes
            sums["mode_linear"] = wd @ modes
            sums["mode_gram"] = weighted_gram(w, modes)
        return cls(**sums)

    def log_likelihood(self, bias_var: float, shift, dof: float = np.inf) -> np.ndarray:
        """The ping's log-likelihood of every hypothesis with its offset ``N(shift, P)``.

        Parameters
        ----------
        bias_var : float
            ``P``, the offset's variance, map units squared (0: the offset known).
        shift : float or numpy.ndarray
            The offsets' means, scalar or the hypotheses' shape, map units.
        dof : float
            A Student-t likelihood's degrees of freedom
            (:func:`geofix.measurement.student_t`); inf: the Gaussian.

        Returns
        -------
        numpy.ndarray
            The hypotheses' shape: log-likelihoods up to a constant (nats), as
            :func:`geofix.measurement.log_likelihood` on predictions plus ``shift``.
        """
        b = np.broadcast_to(np.asarray(shift, dtype=float), self.shape).reshape(-1)
        s, a = self.weight, self.linear
        t = a - b * s
        quad = self.square - b * (2.0 * a - b * s)
        weight, linear, gram = self.mode_weight, self.mode_linear, self.mode_gram
        if weight is None or linear is None or gram is None:
            explained = bias_var * t * t / (1.0 + bias_var * s)
            logdet = np.log1p(bias_var * s)
        else:
            u = np.column_stack(
                [np.sqrt(max(float(bias_var), 0.0)) * t, linear - b[:, None] * weight]
            )
            explained, logdet = _explained(_inner(bias_var, s, weight, gram), u)
        count = 0 if self.count is None else self.count  # the sums of :meth:`of` have it
        ll = student_t(quad - explained, logdet, count, dof)
        ll = ll + OFF_MAP_LOG_LIKELIHOOD * self.off_map
        return ll.reshape(self.shape)


def _own_sums(w, wd, own, modes, beams: int) -> dict:
    """The shape sums of every hypothesis's own columns beside the common ones.

    ``C_i = [own_i, M]`` per hypothesis: ``C_i^T W 1``, ``C_i^T W d`` and ``C_i^T W C_i``
    (the column order does not change a likelihood: Woodbury's form is invariant under
    it).
    """
    m = w.shape[0]
    columns = own.reshape(m, beams, -1)
    if modes is not None:
        common = np.asarray(modes, dtype=float).reshape(beams, -1)
        columns = np.concatenate(
            [columns, np.broadcast_to(common, (m, beams, common.shape[1]))], axis=2
        )
    weighted = columns * w[..., None]  # (m, b, k): W C_i
    return {  # stacked products: several times faster than the einsum forms
        "mode_weight": weighted.sum(axis=1),
        "mode_linear": (wd[:, None, :] @ columns)[:, 0, :],
        "mode_gram": weighted.transpose(0, 2, 1) @ columns,
    }


def _inner(bias_var: float, weight: np.ndarray, mode_weight: np.ndarray, gram: np.ndarray):
    """``(m, c + 1, c + 1)`` ``I + Z^T W Z`` of ``Z = [sqrt(P) 1, M]`` from the sums."""
    m, c = mode_weight.shape
    cross = np.sqrt(max(float(bias_var), 0.0)) * mode_weight  # (m, c): M^T W sqrt(P) 1
    inner = np.empty((m, c + 1, c + 1))
    inner[:, 0, 0] = 1.0 + bias_var * weight
    inner[:, 0, 1:] = cross
    inner[:, 1:, 0] = cross
    inner[:, 1:, 1:] = gram + np.eye(c)
    return inner


def _explained(inner: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u^T inner^-1 u`` and ``log det inner`` of every hypothesis.

    Woodbury's identity and the matrix determinant lemma, as
    :func:`geofix.measurement.low_rank_log_likelihood`; ``inner`` is ``I + Z^T W Z``,
    positive definite, so one Cholesky factor each
    (:func:`geofix.filters._spd_kernels.quadratic_and_logdet`).
    """
    return quadratic_and_logdet(np.ascontiguousarray(inner), np.ascontiguousarray(u))


__all__ = ["ResidualSums"]
