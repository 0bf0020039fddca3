"""Figures of a finished campaign: re-run one trial and draw it beside the campaign's errors."""

from __future__ import annotations

import numpy as np

from geofix.evaluate.campaign import CampaignResult
from geofix.evaluate.crlb import bound_track
from geofix.evaluate.runner import method_rng, run_trial
from geofix.methods import parse_method_spec
from geofix.plot.figures import campaign_figure
from geofix.sim.scenario import Scenario
from geofix.sim.simulate import prepare_map, simulate_trial


def campaign_result_figure(scenario: Scenario, result: CampaignResult, trial: int = 0):
    """:func:`~geofix.plot.figures.campaign_figure` of a campaign's result.

    Trial ``trial`` is simulated again (deterministic: same scenario, same seed) and every
    method of the campaign run on it with the campaign's own generator, so the tracks
    drawn are those the campaign scored.

    Parameters
    ----------
    scenario : Scenario
        The campaign's scenario (with its seed and trial count as run).
    result : CampaignResult
        What :func:`geofix.run_campaign` returned.
    trial : int
        The trial whose tracks are drawn.

    Returns
    -------
    matplotlib.figure.Figure
    """
    grid = prepare_map(scenario)
    shown = simulate_trial(scenario, grid, trial)
    specs = list(result.summary.methods)
    estimates = {
        spec: run_trial(
            parse_method_spec(spec), shown, grid, method_rng(scenario.seed, trial, spec)
        ).estimate
        for spec in specs
        if spec != "ins"  # the INS track is drawn anyway
    }
    frame = result.frame
    errors = {
        spec: np.asarray(frame.loc[frame["method"] == spec, "end_error_m"], dtype=float)
        for spec in specs
    }
    return campaign_figure(
        grid,
        shown.truth,
        shown.indicated,
        estimates,
        errors,
        title=f"{scenario.name}: {result.trials} trials",
        times=shown.times,
        bound_track=bound_track(shown, grid),
        bound_m=result.summary.crlb_m,
    )
