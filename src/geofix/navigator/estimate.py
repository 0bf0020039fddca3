"""The navigator's answer after an input."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True, eq=False)
class Estimate:
    """The navigator's answer after an input.

    Parameters
    ----------
    t : float
        Time of the last input, seconds.
    position : numpy.ndarray
        ``(2,)`` MMSE (posterior mean) position, metres.
    covariance : numpy.ndarray
        ``(2, 2)`` posterior covariance, m^2.
    mle : numpy.ndarray
        ``(2,)`` MLE (posterior mode) position, metres.
    status : str
        One of :data:`~geofix.navigator.settings.STATUSES`.
    nis : float
        Per-beam NIS of the last ping (NaN when not computed).
    accepted : bool
        The last ping was folded in (False: gated out, too few beams, or no ping yet).
    pings, rejected, reinits : int
        Pings seen, pings gated out, re-initialisations so far.
    kl_nats : float
        KL divergence of the posterior to its Gaussian, nats (NaN: not computed -- the
        spread or MLE test failed first -- or a filter without weighted points).
    depth_bias, depth_bias_std : float
        The common-offset state's mean and 1-sigma, map units (measured minus map; NaN
        when ``depth_bias_std`` is 0).
    """

    t: float
    position: np.ndarray
    covariance: np.ndarray
    mle: np.ndarray
    status: str
    nis: float = float("nan")
    accepted: bool = False
    pings: int = 0
    rejected: int = 0
    reinits: int = 0
    kl_nats: float = float("nan")
    depth_bias: float = float("nan")
    depth_bias_std: float = float("nan")

    @property
    def sigma_m(self) -> float:
        """Largest 1-sigma of the covariance, metres."""
        return float(np.sqrt(max(np.linalg.eigvalsh(self.covariance).max(), 0.0)))

    def to_dict(self) -> dict:
        """JSON-ready mapping of the estimate.

        Keys ``t, x, y, cov, status, mle, nis, accepted, pings, rejected, reinits,
        kl_nats, depth_bias`` (``nis``, ``kl_nats``, ``depth_bias`` null when not
        computed).
        """
        return {
            "t": float(self.t),
            "x": float(self.position[0]),
            "y": float(self.position[1]),
            "cov": [[float(v) for v in row] for row in self.covariance],
            "status": self.status,
            "mle": [float(self.mle[0]), float(self.mle[1])],
            "nis": None if not np.isfinite(self.nis) else float(self.nis),
            "accepted": bool(self.accepted),
            "pings": int(self.pings),
            "rejected": int(self.rejected),
            "reinits": int(self.reinits),
            "kl_nats": None if not np.isfinite(self.kl_nats) else float(self.kl_nats),
            "depth_bias": None if not np.isfinite(self.depth_bias) else float(self.depth_bias),
        }


def estimate_fields(estimate: Estimate) -> dict:
    """The fields of an estimate by name (to build another from it)."""
    return {f.name: getattr(estimate, f.name) for f in fields(estimate)}


__all__ = ["Estimate", "estimate_fields"]
