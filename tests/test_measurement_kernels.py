"""The compiled beam read and likelihood sums against their numpy / scipy references."""

import numpy as np
from scipy.ndimage import map_coordinates

from geofix._measurement_kernels import gaussian_log_likelihood, node_field_variance_kernel
from geofix.maps.mapread import bilinear_beams


def test_bilinear_reads_match_map_coordinates_including_edges_and_nans():
    rng = np.random.default_rng(0)
    values = rng.standard_normal((60, 80))
    values[10:12, 20:25] = np.nan
    row, col = rng.uniform(-2, 62, 3000), rng.uniform(-2, 82, 3000)
    row[:5], col[:5] = 59.0, 79.0  # the last cell centre exactly
    row[5:10], col[5:10] = 59.0 + 1e-7, 3.0  # just beyond the edge
    orow, ocol = rng.uniform(-3, 3, 30), rng.uniform(-3, 3, 30)
    orow[0] = ocol[0] = 0.0
    got = bilinear_beams(values, col, row, ocol, orow)
    coords = np.stack([row[:, None] + orow, col[:, None] + ocol]).reshape(2, -1)
    ref = map_coordinates(values, coords, order=1, mode="constant", cval=np.nan, prefilter=False)
    ref = ref.reshape(got.shape)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)
    assert np.isnan(got[5:10, 0]).all() and np.isfinite(got[:5, 0]).all()


def test_likelihood_and_node_variance_kernels_match_numpy():
    rng = np.random.default_rng(1)
    p = rng.standard_normal((21, 25, 30))
    p[3, 4, 5] = np.nan
    y = rng.standard_normal(30)
    y[2] = np.nan
    var = rng.uniform(1, 2, 30)
    use = np.isfinite(y)
    d = p[..., use] - y[use]
    ll = np.where(np.isfinite(d), -0.5 * d**2 / var[use], -1e6).sum(-1)
    got = gaussian_log_likelihood(p.reshape(-1, 30), y, var, -1e6).reshape(21, 25)
    np.testing.assert_allclose(got, ll, rtol=1e-12)
    q = p[..., use]
    ref = 0.0
    for axis in (0, 1):
        diff = np.diff(q, axis=axis)
        ref += np.mean(diff[np.isfinite(diff)] ** 2)
    assert np.isclose(node_field_variance_kernel(p, y), ref / 12.0, rtol=1e-12, atol=0)
