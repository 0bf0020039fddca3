"""
TERCOM on one trial
===================

A method is built from a specification string (``"tercom"``, ``"tercom:metric=mad"``) by
:func:`geofix.parse_method_spec`; :func:`geofix.run_trial` runs it on a
trial the way a campaign does (leg by leg for a batch matcher, with the INS reset to each
fix) and measures its errors against the truth.
"""

import matplotlib.pyplot as plt
import numpy as np

import geofix as gf
from geofix.evaluate import method_rng

scenario = gf.scenario_from_dict(
    {
        "name": "gallery-tercom",
        "map": {"path": "builtin:mb_1km"},
        "track": {
            "start_cell": [50, 50],
            "heading_deg": 45,
            "speed_m_s": 10,
            "interval_s": 60,
            "samples": 20,
            "legs": 3,
            "turn_std_deg": 30,
        },
        "sensor": {"type": "multibeam", "beams": 11, "swath_width_m": 4000, "noise_std": 2.0},
        "ins": {"initial_error_m": [1500, -1000], "velocity_error_m_s": 0.2},
        "trials": 10,
        "seed": 11,
    }
)
grid = gf.prepare_map(scenario)
trial = gf.simulate_trial(scenario, grid, 0)

spec = "tercom"
result = gf.run_trial(gf.parse_method_spec(spec), trial, grid, method_rng(scenario.seed, 0, spec))
ins_end = np.linalg.norm(trial.indicated[-1] - trial.truth[-1])
print(f"INS end error {ins_end:.0f} m; {spec} end error {result.end_error_m:.0f} m")
print("error at the end of each leg (m):", np.round(result.leg_errors_m, 1))
print(f"ambiguous: {result.ambiguous}, {result.n_calls} matches in {result.time_s * 1e3:.1f} ms")

# %%
# The matched track follows the truth leg after leg, while the free INS drifts away.
fig, ax = plt.subplots(figsize=(7, 6))
west, east, south, north = (v / 1000 for v in grid.extent)
image = ax.imshow(grid.values, origin="lower", extent=(west, east, south, north), cmap="cividis")
fig.colorbar(image, ax=ax, label="elevation (m)")
ax.plot(*trial.truth.T / 1000, color="white", linewidth=4, label="true")
ax.plot(*trial.indicated.T / 1000, color="tab:red", linestyle="--", label="INS alone")
ax.plot(*result.estimate.T / 1000, color="tab:orange", marker=".", linewidth=1.2, label=spec)
ax.set_xlabel("east (km)")
ax.set_ylabel("north (km)")
ax.legend(loc="lower right")
plt.show()
