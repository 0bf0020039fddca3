"""Filter sizes against the memory budget: the estimate bounds what a navigator allocates,
and a method, a replay or a gridding beyond the budget is refused before allocating."""

import tracemalloc

import numpy as np
import pytest

from geofix.errors import MemoryBudgetError
from geofix.maps import fractal_terrain
from geofix.maps.gridding import grid_soundings
from geofix.navigator import Navigator, check_method_budget, method_size

BEAMS = 16


@pytest.fixture(scope="module")
def terrain():
    return fractal_terrain((300, 300), 10.0, rng=np.random.default_rng(1), name="sizing")


def navigate(grid, spec: str, steps: int = 3) -> None:
    """Init a navigator with a wide prior, then ``steps`` motions and pings of BEAMS beams."""
    offsets = np.column_stack([np.linspace(-100, 100, BEAMS), np.zeros(BEAMS)])
    nav = Navigator(grid, spec, seed=1)
    start = np.array([1500.0, 1500.0])
    nav.init(0.0, start, 600.0, 0.0)
    for k in range(steps + 1):
        position = start + k * np.array([10.0, 0.0])
        if k:
            nav.motion(float(k), position, 0.0)
        values = grid.sample(position[0] + offsets[:, 0], position[1] + offsets[:, 1])
        nav.measure(float(k), np.column_stack([offsets, values]))


def traced_peak(fn) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize(
    "spec",
    [
        "pf:particles=40000,max_particles=40000,map_model=exact",
        "pmf:points=151,max_points=151,map_model=exact",
        "pf:particles=40000,max_particles=40000,map_model=imperfect",
    ],
)
def test_the_estimate_bounds_the_measured_peak_of_a_navigator(terrain, spec):
    navigate(terrain, spec, 1)  # imports, caches and the compiled paths of this very size
    measured = traced_peak(lambda: navigate(terrain, spec))
    size = method_size(spec, {"max_update_beams": BEAMS}, terrain)
    assert size is not None
    assert measured <= size.peak_bytes <= 4 * measured, (measured, size)


def test_sizes_follow_points_and_beams_and_unsized_filters_are_none(terrain):
    small = method_size("pf:particles=1000,max_particles=1000", {"max_update_beams": 8})
    large = method_size("pf:particles=1000,max_particles=1000", {"max_update_beams": 64})
    exact = method_size("pf:particles=1000,max_particles=1000,map_model=exact")
    assert exact.update_bytes < large.update_bytes  # no offset per hypothesis
    # one common offset marginalised per ping holds half the arrays of one per hypothesis
    common = method_size("pf:particles=1000,max_particles=1000,offset_per_hypothesis=false", {})
    told = method_size("pf:particles=1000,max_particles=1000", {"offset_per_hypothesis": False})
    assert exact.update_bytes < common.update_bytes == told.update_bytes < large.update_bytes
    assert small.points == 1000 and large.update_bytes > 4 * small.update_bytes
    assert method_size("pmf:points=101,max_points=101").points == 101**2
    assert method_size("sitan") is None
    # a map model that reads the map's representation error also holds that layer
    exact = method_size("pmf:map_model=exact", None, terrain)
    adaptive = method_size("pmf:map_model=adaptive", None, terrain)
    assert adaptive.state_bytes - exact.state_bytes == terrain.values.size * 8


def test_a_method_beyond_the_budget_is_refused_with_its_estimate(monkeypatch):
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "256MiB")
    with pytest.raises(MemoryBudgetError, match=r"pf with 2000000 particles x 64 beams .*GiB"):
        check_method_budget("pf:particles=2000000,max_particles=2000000")
    with pytest.raises(MemoryBudgetError, match="mpf with 100000000 particles"):
        check_method_budget("mpf:particles=100000000,max_particles=100000000")
    assert check_method_budget("pf:particles=1000,max_particles=1000").points == 1000


def test_a_replay_beyond_the_budget_is_refused_before_its_filter_is_built(monkeypatch):
    from geofix.logs import read_mission
    from geofix.replay import replay

    mission = read_mission("builtin:ex1811").subset(slice(0, 10))
    x, y, v = mission.soundings().T
    grid = grid_soundings(x, y, v, 100.0, meta={"projection": mission.frame}).grid
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "256MiB")
    spec = "pf:particles=2000000,max_particles=2000000"

    def refused():
        with pytest.raises(MemoryBudgetError, match="pf with 2000000 particles"):
            replay(mission, grid, [spec], initial_error_m=50.0)

    assert traced_peak(refused) < 64 * 2**20  # nothing of two million particles allocated


def test_gridding_is_checked_against_the_budget_not_a_cell_cap(monkeypatch):
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 1000, 500), rng.uniform(0, 1000, 500)
    value = -1000.0 + 0.01 * x
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "256MiB")

    def refused():  # about 3440 x 3440 cells
        with pytest.raises(MemoryBudgetError, match=r"gridding 34\d\d x 34\d\d cells of 0.29 m"):
            grid_soundings(x, y, value, 0.29)

    assert traced_peak(refused) < 16 * 2**20  # refused before the layers were allocated
    # the same soundings at 5 m fit, and a bigger budget takes the fine grid as well
    assert max(grid_soundings(x, y, value, 5.0).grid.shape) == 201
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "2GiB")
    assert grid_soundings(x, y, value, 1.0).grid.values.size > 990_000


def test_a_sitan_bank_linearisation_beyond_the_budget_is_refused_before_it_runs(
    terrain, monkeypatch
):
    navigate(terrain, "sitan-bank:side=3", 1)  # imports and caches
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "32MiB")

    def refused():
        with pytest.raises(MemoryBudgetError, match=r"terrain linearisation of \d+ filters"):
            navigate(terrain, "sitan-bank:side=25")

    assert traced_peak(refused) < 32 * 2**20
    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "4GiB")
    navigate(terrain, "sitan-bank:side=9")  # a smaller bank fits


def test_a_resample_or_regrid_beyond_the_budget_is_refused_before_it_runs(monkeypatch):
    """A campaign filter (no navigator to size it first) is checked at every growth."""
    from geofix.filters.pf import Pf
    from geofix.filters.pmf import check_regrid

    monkeypatch.setenv("GEOFIX_MEMORY_BUDGET", "1MiB")
    with pytest.raises(MemoryBudgetError, match="pmf regrid to 301 x 301 nodes"):
        check_regrid((301, 301))  # 301^2 x 12 x 8 bytes = 8.7 MB
    check_regrid((61, 61))  # 0.36 MB fits
    from geofix.filters.pf import PfState

    rng = np.random.default_rng(0)
    wide = PfState(rng.normal(0.0, 300.0, (100, 2)), np.full(100, -np.log(100)), cell=10.0)
    pf = Pf(particles=100, max_particles=50_000, map_model="exact")
    # a posterior 300 m wide on 10 m cells wants the 50 000 particles: 4.6 MB
    with pytest.raises(MemoryBudgetError, match="pf resample to 50000 particles"):
        pf._resample(wide, rng)
