"""The median by selection that the checks before a walk take, against NumPy's."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rayaccel.selection import median_in_place


@given(arrays(np.float64, st.integers(1, 300), elements=st.floats(-1e6, 1e6)))
def test_median_in_place_is_numpys(values):
    assert median_in_place(values.copy()) == np.median(values)


def test_median_of_sorted_reversed_and_repeated_values():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 1023, 1024):
        for values in (np.arange(n, dtype=np.float64), np.arange(n, 0, -1, dtype=np.float64),
                       rng.integers(0, 3, n).astype(np.float64), np.full(n, 0.5)):
            assert median_in_place(values.copy()) == np.median(values)


def test_a_nan_leaves_the_selection_inside_the_array():
    values = np.random.default_rng(4).random(1000)
    values[::7] = np.nan
    median_in_place(values)
    assert np.isnan(values).sum() == len(values[::7])
