"""The compiled Cholesky of many small SPD systems against LAPACK's solve and determinant."""

import numpy as np
import pytest

from geofix.filters._spd_kernels import quadratic_and_logdet


@pytest.mark.parametrize("k", [1, 2, 3, 5, 8])
def test_the_quadratic_and_logdet_are_lapacks(k):
    rng = np.random.default_rng(k)
    m = 257
    a = rng.normal(size=(m, k, k)) * rng.uniform(0.01, 30.0, (m, 1, 1))
    inner = a @ a.transpose(0, 2, 1) + np.eye(k)  # I + Z^T W Z: eigenvalues >= 1
    u = rng.normal(0.0, 50.0, (m, k))
    quad, logdet = quadratic_and_logdet(inner, u)
    want = np.einsum("mc,mc->m", u, np.linalg.solve(inner, u[..., None])[..., 0])
    np.testing.assert_allclose(quad, want, rtol=1e-10)
    np.testing.assert_allclose(logdet, np.linalg.slogdet(inner)[1], rtol=1e-12, atol=1e-12)


def test_a_matrix_that_is_not_positive_definite_gives_nan_not_a_number_that_looks_right():
    inner = np.array([[[1.0, 0.0], [0.0, 1.0]], [[1.0, 2.0], [2.0, 1.0]]])
    quad, logdet = quadratic_and_logdet(inner, np.ones((2, 2)))
    assert quad[0] == pytest.approx(2.0) and logdet[0] == pytest.approx(0.0)
    assert np.isnan(quad[1]) and np.isnan(logdet[1])
