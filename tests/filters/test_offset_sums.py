"""The residual sums give every offset rate's likelihood as the shifted predictions do."""

import numpy as np
import pytest

from geofix.filters.offset_sums import ResidualSums
from geofix.measurement import OFF_MAP_LOG_LIKELIHOOD, local_field_from_reads, log_likelihood

BEAMS = 12


def _ping(rng, hypotheses=(7, 5)):
    """Predictions with a few off-map reads, a ping with a missing beam, per-beam variances."""
    predicted = rng.normal(100.0, 5.0, (*hypotheses, BEAMS))
    flat = predicted.reshape(-1, BEAMS)  # a view
    flat[0, 3] = np.nan  # read off the map
    flat[5, :4] = np.nan
    measured = rng.normal(100.0, 5.0, BEAMS)
    measured[7] = np.nan  # a missing beam
    return predicted, measured, rng.uniform(0.5, 4.0, BEAMS)


def _modes(rng):
    """Two shapes across the swath times their 1-sigma, map units."""
    a = np.linspace(-1.0, 1.0, BEAMS)
    return np.column_stack([2.0 * a, 0.7 * (a * a - np.mean(a * a))]) + 0.01 * rng.normal(
        size=(BEAMS, 2)
    )


@pytest.mark.parametrize("bias_var", [0.0, 0.3, 25.0])
@pytest.mark.parametrize("with_modes", [False, True])
def test_every_rate_matches_the_likelihood_of_the_shifted_predictions(bias_var, with_modes):
    rng = np.random.default_rng(3)
    predicted, measured, var = _ping(rng)
    modes = _modes(rng) if with_modes else None
    shift = rng.normal(0.0, 8.0, predicted.shape[:-1])
    sums = ResidualSums.of(predicted, measured, var, modes)
    got = sums.log_likelihood(bias_var, shift)
    want = log_likelihood(predicted + shift[..., None], measured, var, bias_var, modes)
    assert got.shape == predicted.shape[:-1]
    # relative to the spread of the hypotheses' values (the off-map reads cost 1e6 each)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    # an off-map read is counted once per beam it misses, whatever the shift
    off = got.reshape(-1)
    assert OFF_MAP_LOG_LIKELIHOOD * 1.5 < off[0] < OFF_MAP_LOG_LIKELIHOOD / 2
    assert OFF_MAP_LOG_LIKELIHOOD * 4.5 < off[5] < OFF_MAP_LOG_LIKELIHOOD * 3.5


def test_a_variance_per_hypothesis_and_beam_is_weighed_as_given():
    rng = np.random.default_rng(4)
    predicted, measured, _ = _ping(rng, (9,))
    var = rng.uniform(0.5, 4.0, predicted.shape)
    shift = rng.normal(0.0, 3.0, 9)
    got = ResidualSums.of(predicted, measured, var).log_likelihood(2.0, shift)
    want = log_likelihood(predicted + shift[:, None], measured, var, 2.0)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)


def test_a_large_common_shift_keeps_the_differences_between_hypotheses():
    # the sums expand (d - b)^2; an offset of hundreds of units against residuals of the
    # same size must not lose the hypotheses' differences to rounding
    rng = np.random.default_rng(5)
    predicted, measured, var = _ping(rng, (40,))
    predicted = predicted - 500.0
    shift = 500.0 + rng.normal(0.0, 0.5, 40)
    got = ResidualSums.of(predicted, measured, var).log_likelihood(1.0, shift)
    want = log_likelihood(predicted + shift[:, None], measured, var, 1.0)
    on_map = np.isfinite(predicted).all(axis=1)
    assert np.ptp(want[on_map]) > 1.0
    np.testing.assert_allclose(
        got[on_map] - got[on_map][0], want[on_map] - want[on_map][0], atol=1e-7
    )


@pytest.mark.parametrize("bias_var", [0.0, 0.3, 25.0])
@pytest.mark.parametrize("with_modes", [False, True])
def test_each_hypothesis_own_columns_match_the_local_field_likelihood(bias_var, with_modes):
    # the local field variance: each hypothesis's own change within its share, two
    # columns per hypothesis, marginalised beside the offset and the common shapes
    rng = np.random.default_rng(6)
    predicted, measured, var = _ping(rng)
    shape = predicted.shape[:-1]
    f0 = predicted.reshape(-1, BEAMS)
    own = rng.normal(0.0, 1.5, (f0.shape[0], BEAMS, 2))
    own[~np.isfinite(f0)] = 0.0  # as local_field_reads leaves a read off the map
    modes = _modes(rng) if with_modes else None
    shift = rng.normal(0.0, 8.0, shape)
    got = ResidualSums.of(predicted, measured, var, modes, own).log_likelihood(bias_var, shift)
    want = local_field_from_reads((f0, own, shape), measured, var, bias_var, shift, modes)
    assert got.shape == shape
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    # the own columns widen the likelihood: without them it is another number
    plain = ResidualSums.of(predicted, measured, var, modes).log_likelihood(bias_var, shift)
    on_map = np.isfinite(predicted.reshape(-1, BEAMS)).all(axis=1)
    assert np.abs(plain.reshape(-1) - got.reshape(-1))[on_map].min() > 1e-6
