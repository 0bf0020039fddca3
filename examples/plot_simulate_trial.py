"""
Simulate one trial
==================

A scenario describes a family of missions: the map, the true track, the field sensor and
the INS datasheet. Trial ``i`` is drawn from ``numpy.random.default_rng([seed, i])`` alone,
so any trial can be regenerated on its own. Here: a single-beam echosounder on a vehicle
crossing the bundled 1 km multibeam grid, with an INS whose initial error and velocity
error make the indicated track drift away from the true one.
"""

import matplotlib.pyplot as plt
import numpy as np

import geofix as gf

scenario = gf.scenario_from_dict(
    {
        "name": "gallery-single-beam",
        "map": {"path": "builtin:mb_1km"},
        "track": {
            "start_cell": [50, 50],
            "heading_deg": 45,
            "speed_m_s": 10,
            "interval_s": 60,
            "samples": 40,
        },
        "sensor": {"type": "singlebeam", "noise_std": 2.0},
        "ins": {"initial_error_m": [1500, -1000], "velocity_error_m_s": 0.3},
        "trials": 10,
        "seed": 7,
    }
)
grid = gf.prepare_map(scenario)
trial = gf.simulate_trial(scenario, grid, 0)
print(f"{trial.n} samples, {trial.measured.shape[1]} beam(s), map {grid}")

# %%
# The true and the indicated (INS) tracks on the map, and the INS error over time beside
# the prior 1-sigma the INS error model predicts for it (per axis).
fig, (ax_map, ax_err) = plt.subplots(1, 2, figsize=(12, 5), width_ratios=[1.1, 1])
west, east, south, north = (v / 1000 for v in grid.extent)
image = ax_map.imshow(
    grid.values, origin="lower", extent=(west, east, south, north), cmap="cividis"
)
fig.colorbar(image, ax=ax_map, label="elevation (m)")
ax_map.plot(*trial.truth.T / 1000, color="white", linewidth=2.5, label="true")
ax_map.plot(*trial.indicated.T / 1000, color="tab:red", linestyle="--", label="indicated (INS)")
ax_map.set_xlabel("east (km)")
ax_map.set_ylabel("north (km)")
ax_map.legend(loc="lower right")

minutes = (trial.times - trial.times[0]) / 60
ins_error = np.linalg.norm(trial.indicated - trial.truth, axis=1)
ax_err.plot(minutes, ins_error, label="INS position error")
ax_err.plot(minutes, np.sqrt(2) * trial.sigma_position, linestyle=":", label="prior RMS (2 axes)")
ax_err.set_xlabel("time (min)")
ax_err.set_ylabel("error (m)")
ax_err.legend()
fig.tight_layout()

# %%
# The measured depths (true map under the true track, plus noise) against the map read
# under the indicated track: the mismatch is what a matcher removes.
fig, ax = plt.subplots(figsize=(9, 3.5))
ax.plot(minutes, trial.measured[:, 0], marker=".", label="measured")
ax.plot(minutes, grid.sample(*trial.indicated.T), label="map under the indicated track")
ax.set_xlabel("time (min)")
ax.set_ylabel("elevation (m)")
ax.legend()
fig.tight_layout()
plt.show()
