"""Least-squares rigid transforms (Kabsch / Umeyama by SVD), shared by ICCP and ICP."""

from __future__ import annotations

import numpy as np


def rigid_transform(
    source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation that best map ``source`` points onto ``target`` points.

    Minimises ``sum_i w_i |R p_i + t - q_i|^2`` over proper rotations ``R`` (det +1):
    centroids ``mu_p``, ``mu_q``; ``H = sum_i w_i (p_i - mu_p)(q_i - mu_q)^T = U S V^T``;
    ``R = V diag(1, ..., det(V U^T)) U^T`` (the reflection guard); ``t = mu_q - R mu_p``.

    Parameters
    ----------
    source, target : numpy.ndarray
        ``(n, d)`` corresponding points (d = 2 or 3), same units (metres).
    weights : numpy.ndarray, optional
        ``(n,)`` non-negative weights; equal by default.

    Returns
    -------
    rotation : numpy.ndarray
        ``(d, d)`` proper rotation matrix.
    translation : numpy.ndarray
        ``(d,)`` translation, same units as the points.
    """
    p = np.asarray(source, dtype=float)
    q = np.asarray(target, dtype=float)
    if p.shape != q.shape or p.ndim != 2 or p.shape[0] < 2:
        raise ValueError(f"need two (n, d) arrays of the same shape, got {p.shape}, {q.shape}")
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_p = w @ p
    mu_q = w @ q
    h = (p - mu_p).T @ ((q - mu_q) * w[:, None])
    u, _, vt = np.linalg.svd(h)
    guard = np.eye(p.shape[1])
    guard[-1, -1] = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ guard @ u.T
    return rotation, mu_q - rotation @ mu_p


def rotation_2d(theta: float) -> np.ndarray:
    """Counter-clockwise rotation by ``theta`` radians in the (x east, y north) plane."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def apply_transform(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray):
    """``R p + t`` for every row ``p`` of ``points``.

    Parameters
    ----------
    points : numpy.ndarray
        ``(n, d)`` points, metres.
    rotation : numpy.ndarray
        ``(d, d)`` rotation matrix ``R``.
    translation : numpy.ndarray
        ``(d,)`` translation ``t``, metres.

    Returns
    -------
    numpy.ndarray
        ``(n, d)`` transformed points, metres.
    """
    return np.asarray(points) @ rotation.T + translation
