"""The SVD rigid transform is exact on synthetic point sets (property test)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from geofix.match.rigid import apply_transform, rigid_transform, rotation_2d


@settings(max_examples=60, deadline=None)
@given(
    theta=st.floats(-np.pi, np.pi),
    tx=st.floats(-1e4, 1e4),
    ty=st.floats(-1e4, 1e4),
    seed=st.integers(0, 2**32 - 1),
)
def test_recovers_any_2d_rigid_transform_exactly(theta, tx, ty, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-500, 500, size=(12, 2))
    r = rotation_2d(theta)
    q = apply_transform(p, r, np.array([tx, ty]))
    r_est, t_est = rigid_transform(p, q)
    np.testing.assert_allclose(r_est, r, atol=1e-9)
    np.testing.assert_allclose(t_est, [tx, ty], atol=1e-6)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_recovers_3d_rotation_and_never_a_reflection(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3))
    qmat, rmat = np.linalg.qr(a)
    rot = qmat @ np.diag(np.sign(np.diag(rmat)))
    if np.linalg.det(rot) < 0:
        rot[:, 0] *= -1
    p = rng.normal(0, 100, size=(20, 3))
    t = rng.normal(0, 50, size=3)
    r_est, t_est = rigid_transform(p, apply_transform(p, rot, t))
    np.testing.assert_allclose(r_est, rot, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-7)
    assert np.linalg.det(r_est) > 0


def test_mirrored_points_give_a_proper_rotation():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [3.0, 1.0]])
    q = p * np.array([-1.0, 1.0])  # a reflection: no rotation reproduces it
    r_est, _ = rigid_transform(p, q)
    assert np.linalg.det(r_est) > 0


def test_weights_ignore_an_outlier():
    rng = np.random.default_rng(0)
    p = rng.normal(0, 10, size=(10, 2))
    q = apply_transform(p, rotation_2d(0.2), np.array([5.0, -3.0]))
    q[0] += 1000.0
    w = np.ones(10)
    w[0] = 0.0
    r_est, t_est = rigid_transform(p, q, w)
    np.testing.assert_allclose(r_est, rotation_2d(0.2), atol=1e-9)
    np.testing.assert_allclose(t_est, [5.0, -3.0], atol=1e-8)
