"""Mean Hausdorff distance (Dubuisson & Jain 1994): hand-computed values and properties."""

import numpy as np
import pytest

from geofix.match._hausdorff import (
    batch_mean_hausdorff,
    directed_mean_distance,
    hausdorff,
    mean_hausdorff,
)

A = np.array([[0.0, 0.0], [1.0, 0.0]])
B = np.array([[0.0, 1.0], [3.0, 0.0]])


def test_directed_mean_distance_by_hand():
    # A -> B: (0,0) is 1 from (0,1); (1,0) is sqrt(2) from (0,1) -> mean (1 + sqrt 2) / 2
    assert directed_mean_distance(A, B) == pytest.approx((1.0 + np.sqrt(2.0)) / 2.0)
    # B -> A: (0,1) is 1 from (0,0); (3,0) is 2 from (1,0) -> mean 1.5
    assert directed_mean_distance(B, A) == pytest.approx(1.5)


def test_mean_hausdorff_by_hand_and_symmetric():
    assert mean_hausdorff(A, B) == pytest.approx(1.5)
    assert mean_hausdorff(B, A) == pytest.approx(1.5)
    assert mean_hausdorff(A, A) == 0.0


def test_classic_hausdorff_by_hand_is_larger():
    assert hausdorff(A, B) == pytest.approx(2.0)
    assert mean_hausdorff(A, B) < hausdorff(A, B)


def test_one_outlier_moves_mean_variant_by_a_share_only():
    line = np.stack([np.arange(10.0), np.zeros(10)], axis=1)
    moved = line.copy()
    moved[4, 1] = 100.0
    assert hausdorff(line, moved) == pytest.approx(100.0)
    # d(moved, line) = 100 / 10; d(line, moved) = 1 / 10 (point 4 now 1 from its neighbours)
    assert mean_hausdorff(line, moved) == pytest.approx(10.0)


def test_batch_matches_single(rng):
    a = rng.normal(size=(3, 4, 7, 2))
    b = rng.normal(size=(3, 4, 5, 2))
    batch = batch_mean_hausdorff(a, b)
    assert batch.shape == (3, 4)
    for i in range(3):
        for j in range(4):
            assert batch[i, j] == pytest.approx(mean_hausdorff(a[i, j], b[i, j]))


def test_empty_set_raises():
    with pytest.raises(ValueError, match="non-empty"):
        mean_hausdorff(np.zeros((0, 2)), A)
