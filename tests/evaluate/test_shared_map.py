"""Map sharing for local workers: storage precision, shared block, bounded submission."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from geofix.evaluate import _shared_map
from geofix.evaluate._pool import bounded
from geofix.evaluate.campaign import _pending_count, _pending_tasks
from geofix.maps.grid import Grid


def _depth_grid(peak=4000.0):
    rng = np.random.default_rng(0)
    values = -peak + rng.normal(0, 50.0, (40, 50))
    values[3, 4] = np.nan
    return Grid(values, 10.0, 20.0, 5.0, 5.0, name="deep", meta={"source": "test"})


def test_float32_only_where_rounding_is_negligible_against_the_noise():
    grid = _depth_grid()
    assert _shared_map.storage_dtype(grid.values, 0.1) == np.float32
    # 4.2 km depths round by up to 2.5e-4 m: too much for a 1e-3 m sensor (1 %)
    assert _shared_map.storage_dtype(grid.values, 1e-3) == np.float64
    assert _shared_map.storage_dtype(grid.values, 0.0) == np.float64
    compact = _shared_map.as_storage(grid, 0.1)
    assert compact.values.dtype == np.float32 and not compact.values.flags.writeable
    error = np.nanmax(np.abs(compact.values.astype(float) - grid.values))
    assert 0 < error <= 0.01 * 0.1
    assert compact.x0 == grid.x0 and compact.meta == grid.meta
    assert _shared_map.as_storage(grid, 1e-3) is grid


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_attached_grid_reads_the_shared_block_without_a_copy(dtype):
    grid = _shared_map.as_storage(_depth_grid(), 0.1 if dtype == np.float32 else 0.0)
    with _shared_map.SharedGrid(grid, dtype) as shared:
        other = _shared_map.attach(shared.handle)
        assert other.values.dtype == dtype
        assert not other.values.flags.writeable and not other.values.flags.owndata
        np.testing.assert_array_equal(other.values, grid.values)
        x, y = np.array([30.0, 101.3, 200.0]), np.array([40.0, 77.7, 150.0])
        np.testing.assert_array_equal(other.sample(x, y), grid.sample(x, y))
        assert (other.name, other.kind, other.dx, other.meta) == ("deep", "depth", 5.0, grid.meta)
        _shared_map._ATTACHED.pop().close()
        del other


def test_pending_tasks_are_lazy_and_counted_without_listing_them():
    parsed = {"a": object(), "b": object()}
    done = {("a", 0), ("b", 0), ("a", 2), ("zz", 1), ("a", 10**7)}
    tasks = _pending_tasks(parsed, 10**6, done)
    assert next(tasks)[0] == 1  # trial 0 is complete
    index, todo = next(tasks)
    assert index == 2 and [spec for spec, _ in todo] == ["b"]
    assert _pending_count(parsed, 10**6, done) == (10**6 - 1, 2 * 10**6 - 3)


def test_bounded_submission_keeps_few_tasks_in_flight():
    in_flight, peak = [0], [0]

    def work(task):
        return task * 2

    with ThreadPoolExecutor(2) as pool:

        def submit(task):
            in_flight[0] += 1
            peak[0] = max(peak[0], in_flight[0])
            future = pool.submit(work, task)
            return future

        results = []
        for value in bounded(submit, iter(range(100)), 5):
            in_flight[0] -= 1
            results.append(value)
    assert sorted(results) == [2 * t for t in range(100)]
    assert peak[0] <= 5 + 1  # the limit, plus the result being handed over


def test_chunks_follow_the_measured_task_time_and_share_out_the_last_tasks():
    from geofix.evaluate._pool import CHUNK_TARGET_S, MAX_CHUNK, Chunker

    chunker = Chunker(iter(range(1000)), left=1000, jobs=2)
    assert [len(chunker.next()) for _ in range(3)] == [1, 1, 1]  # nothing measured yet
    chunker.observe(3, 3 * CHUNK_TARGET_S / 10)  # tasks of a tenth of the target
    assert len(chunker.next()) == 10
    chunker.observe(1000, 1e-6)  # very quick tasks: capped
    assert len(chunker.next()) == MAX_CHUNK
    # near the end a chunk holds at most the tasks left over twice the workers
    rest = Chunker(iter(range(20)), left=20, jobs=2)
    rest.observe(1, 1e-6)
    sizes = []
    while chunk := rest.next():
        sizes.append(len(chunk))
    assert sum(sizes) == 20 and sizes[0] == 5 and sizes[-1] == 1
