"""Wall-clock timing shared by calibration, experiments and benchmarks."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["median_seconds"]


def median_seconds(run, repeats: int = 5) -> float:
    """Median wall time of ``run()`` over ``repeats`` runs, after one untimed warm-up run."""
    run()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return float(np.median(times))
