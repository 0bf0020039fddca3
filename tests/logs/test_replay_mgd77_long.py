"""A long real single-beam ship track replayed at default settings against a map made by others.

The bundled EW0112 excerpt's first 22 hours (R/V Maurice Ewing, 2001, one centre-beam
depth a minute, GNSS as the truth) against the bundled ETOPO1 crop at 10 arc-minutes, an
INS drift simulated by the replay's defaults (a free inertial navigator), ``pmf`` at its
default settings.
"""

import warnings
from pathlib import Path

import numpy as np
import pytest

from geofix.errors import GeofixWarning
from geofix.logs.mgd77 import field_segments, pick_segment
from geofix.maps import load_grid
from geofix.replay import nees, replay, window_mission

DATA = Path(__file__).parents[1] / "data" / "mgd77"
HOURS = 22.0
#: The 2-D 3-sigma: ``e^T C^-1 e`` within the covariance's 99.73 % ellipse.
NEES_3SIGMA = 11.83
#: Pings in six hours (one a minute): the window over which the estimate must move with the INS.
WINDOW = 360


@pytest.fixture(scope="module")
def long_replay():
    grid = load_grid(DATA / "etopo1_10min_ew0112.nc")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeofixWarning)  # the excerpt's placed times
        _, missions = field_segments(
            DATA / "ew0112_excerpt.m77t", "depth", frame=grid.meta["projection"]
        )
    mission = window_mission(pick_segment(missions, None), 0.0, HOURS)
    result = replay(mission, grid, ["pmf"], seed=1)
    ests = result.estimates["pmf"]
    return result.inputs, ests


def test_the_estimate_follows_the_ins_motion_over_the_whole_track(long_replay):
    inputs, ests = long_replay
    est = np.array([e.position for e in ests])
    assert len(ests) > 20 * 60 and np.isfinite(est).all()
    steamed = np.hypot(*np.diff(inputs.truth, axis=0).T).sum()
    # a frozen estimate stays where it was lost and ends hundreds of kilometres off
    # (312 km after 22 h was measured on such a track)
    assert np.hypot(*(est[-1] - inputs.truth[-1])) < 0.25 * steamed
    # between its corrections the estimate moves with the INS: over most six-hour windows
    # its offset from the INS changes by well under the distance the INS moved
    offset = est - inputs.indicated
    changed = np.hypot(*(offset[WINDOW:] - offset[:-WINDOW]).T)
    ins_moved = np.hypot(*(inputs.indicated[WINDOW:] - inputs.indicated[:-WINDOW]).T)
    assert np.median(changed / ins_moved) < 0.5


def test_the_long_track_claims_nothing_its_covariance_does_not_hold(long_replay):
    inputs, ests = long_replay
    converged = np.array([e.status == "converged" for e in ests])
    scores = nees(ests, inputs.truth)
    assert converged.sum() > 20  # it does claim: the test is not passed by silence
    # 117 pings claimed converged beyond 3 sigma (44 km off with a 1-sigma of 9 km) before
    # the filters took the relief the readings show and the map lacks as a map error
    assert not (converged & (scores > NEES_3SIGMA)).any()
    # and the covariance holds the error along the whole track, not only where it claims
    assert np.mean(scores <= NEES_3SIGMA) > 0.95


@pytest.mark.xfail(
    strict=True,
    reason="against a 10' grid one depth a minute holds the position little better than the "
    "INS: pmf follows the INS within its covariance (median NEES 1.3) and ends 36.8 km off, "
    "the INS alone 34.9 km; over replay seeds 1-8 pmf ends 25.0-36.8 km off (mean 29.6 km) "
    "against the INS's 34.8-34.9 km, farther than the INS on seeds 1 and 3 (pf 21.9-43.3 km "
    "and mpf 23.1-39.5 km, farther on the same two)",
)
def test_the_long_track_ends_no_worse_than_the_ins(long_replay):
    inputs, ests = long_replay
    est = np.array([e.position for e in ests])
    end = np.hypot(*(est[-1] - inputs.truth[-1]))
    ins_end = np.hypot(*(inputs.indicated[-1] - inputs.truth[-1]))
    assert end <= ins_end
