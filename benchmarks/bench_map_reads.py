"""The fused likelihoods' map read inside the map against the checked read, ns a read.

:func:`geofix._likelihood_kernels._beam_major_reads` reads every footprint of a block of
hypotheses beam by beam; where all of them lie inside the map it takes the unchecked
two-loop read, elsewhere :func:`geofix.maps.mapread.bilinear_at` (bounds and no-data
checks). Both run here, alternately, on the same 33 beams x 61 hypotheses of a
1207 x 1171 map (source 001's size) and must agree to the bit; the median of the pair
ratios is the same-run figure.

Usage: ``NUMBA_NUM_THREADS=1 python benchmarks/bench_map_reads.py [--pairs 7]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from geofix._likelihood_kernels import _beam_major_reads

BEAMS, HYPOTHESES, REPEATS = 33, 61, 2000


def _inputs(seed: int = 0):
    rng = np.random.default_rng(seed)
    values = np.ascontiguousarray(rng.normal(size=(1207, 1171)))
    cols = 500 + rng.uniform(0, 20, HYPOTHESES)
    rows = 500 + rng.uniform(0, 20, HYPOTHESES)
    bcol, brow = rng.uniform(-15, 15, BEAMS), rng.uniform(-15, 15, BEAMS)
    return values, cols, rows, bcol, brow


def _ns_per_read(inside: bool, args, out) -> float:
    values, cols, rows, bcol, brow = args
    start = time.perf_counter()
    for _ in range(REPEATS):
        _beam_major_reads(values, cols, rows, HYPOTHESES, bcol, brow, inside, out)
    return (time.perf_counter() - start) / (REPEATS * BEAMS * HYPOTHESES) * 1e9


def main() -> None:
    """Print both times and their ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=7)
    args = parser.parse_args()
    inputs = _inputs()
    fast, checked = np.empty((BEAMS, HYPOTHESES)), np.empty((BEAMS, HYPOTHESES))
    _ns_per_read(True, inputs, fast)  # compile / load both
    _ns_per_read(False, inputs, checked)
    if not np.array_equal(fast, checked):
        raise SystemExit("the two reads disagree")
    pairs = [
        (_ns_per_read(True, inputs, fast), _ns_per_read(False, inputs, checked))
        for _ in range(args.pairs)
    ]
    a, b = np.array(pairs).T
    print(
        f"inside {np.median(a):.2f} ns a read, checked {np.median(b):.2f} ns, "
        f"ratio {np.median(b / a):.2f} (median of {len(pairs)} pairs)"
    )


if __name__ == "__main__":
    main()
