"""The filter-state protocol: every state class offers moments, mode and points, and the
readers built on it (posterior points, the MLE position, memory sizing) give what the
attribute probing they replace gave."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.special import logsumexp

from geofix.filters.convergence import posterior_points
from geofix.filters.motion import InsErrorState, RandomWalk
from geofix.filters.mpf import Mpf, MpfState
from geofix.filters.pf import ParticleSettings, Pf, PfState
from geofix.filters.pmf import Pmf, PmfState
from geofix.filters.sitan import BankState, Sitan, SitanBank, SitanState
from geofix.filters.sizing import filter_points
from geofix.filters.state import FilterState, mode_position
from geofix.methods import parse_method_spec


def _pf_state(rng):
    particles = rng.normal(100.0, 20.0, (300, 2))
    log_weight = rng.normal(0.0, 2.0, 300)
    return PfState(particles, log_weight - logsumexp(log_weight), 10.0, spacing=5.0)


def _pmf_state(rng):
    log_weight = rng.normal(0.0, 2.0, (9, 7))
    axes = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    return PmfState(
        log_weight - logsumexp(log_weight),
        np.array([50.0, -20.0]),
        axes,
        np.array([3.0, 4.0]),
        10.0,
    )


def _mpf_state(rng):
    dp = rng.normal(0.0, 20.0, (200, 2))
    log_weight = rng.normal(0.0, 1.0, 200)
    return MpfState(
        dp=dp,
        linear=np.zeros((200, 3)),
        cov=np.eye(3),
        log_weight=log_weight - logsumexp(log_weight),
        indicated=np.array([10.0, 20.0]),
        step=0,
        model=None,
        dvl=None,
        cell=10.0,
    )


def _sitan_state():
    return SitanState(np.array([10.0, 20.0]), np.arange(5.0), np.eye(5) * 4.0)


def _bank_state():
    x = np.arange(20.0).reshape(4, 5)
    return BankState(
        np.array([1.0, 2.0]), x, np.stack([np.eye(5)] * 4), np.array([3, 1, 2, 4.0]), 2, 5.0
    )


def test_every_state_class_offers_the_protocol():
    rng = np.random.default_rng(0)
    states = [_pf_state(rng), _pmf_state(rng), _mpf_state(rng), _sitan_state(), _bank_state()]
    for state in states:
        assert isinstance(state, FilterState)
        mean, cov = state.moments()
        assert mean.shape == (2,) and cov.shape == (2, 2)
        assert state.mode().shape == (2,)


def test_the_mode_is_the_highest_weight_and_the_mle_follows_the_old_rules():
    rng = np.random.default_rng(1)
    pf = _pf_state(rng)
    best = int(np.argmax(pf.log_weight))
    np.testing.assert_array_equal(mode_position(Pf(), pf), pf.particles[best])
    pmf = _pmf_state(rng)
    i, j = np.unravel_index(int(np.argmax(pmf.log_weight)), pmf.shape)
    u = np.array([i, j]) - 0.5 * (np.array(pmf.shape) - 1)
    want = pmf.centre + pmf.axes @ (u * pmf.spacing)
    np.testing.assert_array_equal(mode_position(Pmf(), pmf), want)
    # the marginalised set reports its weighted mean; its state's mode is its best particle
    mpf = _mpf_state(rng)
    np.testing.assert_array_equal(mode_position(Mpf(), mpf), Mpf().estimate(mpf)[0])
    np.testing.assert_array_equal(mpf.mode(), mpf.positions[np.argmax(mpf.log_weight)])
    for filt, state in ((Sitan(), _sitan_state()), (SitanBank(), _bank_state())):
        np.testing.assert_array_equal(mode_position(filt, state), filt.estimate(state)[0])


def test_posterior_points_of_grids_particles_and_kalman_filters():
    rng = np.random.default_rng(2)
    pmf = _pmf_state(rng)
    points, weights, area = posterior_points(pmf)
    assert points.shape == (63, 2) and area == pytest.approx(12.0)
    np.testing.assert_allclose(weights.sum(), 1.0)
    np.testing.assert_allclose(weights @ points, pmf.moments()[0])
    pf = _pf_state(rng)
    points, weights, area = posterior_points(pf)
    assert (area is None and points is pf.particles) or np.array_equal(points, pf.particles)
    mpf = _mpf_state(rng)
    np.testing.assert_array_equal(posterior_points(mpf)[0], mpf.positions)
    assert posterior_points(_sitan_state()) is None
    assert posterior_points(_bank_state()) is None
    assert posterior_points(object()) is None


def test_sized_filters_declare_their_points():
    assert filter_points(Pf(max_particles=7000)) == ("pf", 7000)
    assert filter_points(Mpf(max_particles=8000)) == ("mpf", 8000)
    assert filter_points(Pmf(points=101, max_points=201)) == ("pmf", 201**2)
    assert filter_points(Sitan()) is None and filter_points(SitanBank()) is None


def test_the_model_setting_selects_the_motion_component_and_the_particle_settings_are_one():
    with_ins, without_ins = SimpleNamespace(ins_model=object()), SimpleNamespace(ins_model=None)
    assert isinstance(parse_method_spec("pmf:model=rw").motion_model_for(with_ins), RandomWalk)
    errstate = parse_method_spec("pmf:model=errstate,use_dvl=false")
    assert errstate.motion_model_for(without_ins) == InsErrorState(use_dvl=False)
    assert errstate.needs_ins_model
    auto = parse_method_spec("pmf")  # the default takes the error state where there is one
    assert auto.model == "auto" and not auto.needs_ins_model
    assert auto.motion_model_for(with_ins) == InsErrorState(use_dvl=True)
    assert isinstance(auto.motion_model_for(without_ins), RandomWalk)
    shared = {f.name for f in dataclasses.fields(ParticleSettings)}
    assert shared <= {f.name for f in dataclasses.fields(Pf)}
    assert shared <= {f.name for f in dataclasses.fields(Mpf)}
    assert Pf().likelihood == Mpf().likelihood
