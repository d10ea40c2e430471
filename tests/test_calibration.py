"""The grid cost model's calibration: the fit, the fallback, the cache and the pinned ratio.

No test here depends on a timing: the timer is replaced by synthetic times built from the
real kernel's counters, so each expected result is known exactly.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import rayaccel as ra
from rayaccel.scene import SPHERE, TRIANGLE
from rayaccel.structures.grid import calibrate as cal

CELL_STEP = 4e-9
INTERSECTION = 10e-9
SETUP = 50e-9


def _linear_timer(traversals, repeats):
    """Seconds per ray exactly ``SETUP + C_c * cells + C_i * tests``."""
    return np.array([SETUP + CELL_STEP * t.cells_per_ray + INTERSECTION * t.tests_per_ray for t in traversals])


def _noise_timer(traversals, repeats):
    """Times that fall as the work grows: no positive slope can be fitted."""
    return np.linspace(1e-6, 1e-7, len(traversals))


@pytest.fixture
def unpinned(monkeypatch, tmp_path):
    """No pinned ratio and an empty cache of its own."""
    monkeypatch.delenv(cal.RATIO_VARIABLE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    cal._warned.clear()
    return tmp_path


def test_theil_sen_recovers_a_line_and_ignores_one_outlier():
    x = np.arange(1.0, 10.0)
    y = 3.0 * x + 2.0
    assert cal.fit_slope(x, y) == pytest.approx((3.0, 2.0))
    y[4] *= 50.0
    slope, intercept = cal.fit_slope(x, y)
    assert slope == pytest.approx(3.0, rel=0.2)
    assert np.isnan(cal.fit_slope(np.ones(4), np.arange(4.0))[0])


@pytest.mark.parametrize("kind", [TRIANGLE, SPHERE])
def test_the_sweeps_isolate_steps_and_tests(kind):
    rng = np.random.default_rng(0)
    steps = cal._step_traversals(kind, rng)
    tests = cal._test_traversals(kind, rng)
    assert all(t.tests_per_ray == 0 for t in steps)
    cells = [t.cells_per_ray for t in steps]
    assert cells == sorted(cells) and cells[-1] > 5 * cells[0]
    assert all(t.cells_per_ray == 1 for t in tests)
    assert [t.tests_per_ray for t in tests] == list(cal._TEST_COUNTS)


@pytest.mark.parametrize("kind", [TRIANGLE, SPHERE])
def test_calibration_fits_the_costs_of_the_real_counters(monkeypatch, kind):
    monkeypatch.setattr(cal, "_timed", _linear_timer)
    entry = cal.calibrate(kind)
    assert entry["ok"]
    assert entry["cell_step_seconds"] == pytest.approx(CELL_STEP, rel=1e-6)
    assert entry["intersection_seconds"] == pytest.approx(INTERSECTION, rel=1e-6)
    assert entry["ray_setup_seconds"] == pytest.approx(SETUP, rel=1e-6)
    assert entry["ratio"] == pytest.approx(INTERSECTION / CELL_STEP, rel=1e-6)
    assert entry["uncertainty"] == pytest.approx(0.0, abs=1e-9)


def test_a_failed_fit_is_retried_then_falls_back_with_a_warning(monkeypatch, unpinned):
    calls = []

    def failing(traversals, repeats):
        calls.append(1)
        return _noise_timer(traversals, repeats)

    monkeypatch.setattr(cal, "_timed", failing)
    with pytest.warns(RuntimeWarning, match="rayaccel calibrate"):
        entry = cal.calibration(SPHERE)
    assert entry["source"] == "default" and entry["ratio"] == cal.DEFAULT_RATIOS[SPHERE]
    assert len(calls) == cal.ATTEMPTS
    with pytest.warns(RuntimeWarning, match="rayaccel calibrate"):
        assert cal.cost_ratio(SPHERE) == cal.DEFAULT_RATIOS[SPHERE]
    assert len(calls) == cal.ATTEMPTS, "the fallback is cached, not measured again at every build"


def test_cost_resolution_always_returns_a_grid(monkeypatch, unpinned):
    monkeypatch.setattr(cal, "_timed", _noise_timer)
    scene = ra.random_spheres(500, seed=1)
    with pytest.warns(RuntimeWarning):
        grid = ra.build(scene, "grid", resolution="cost")
    expected = 2 * len(scene) * cal.DEFAULT_RATIOS[SPHERE]
    assert 0.6 * expected < grid.stats()["nodes"] < 1.6 * expected


def test_a_good_fit_is_cached_and_refresh_measures_again(monkeypatch, unpinned):
    calls = []

    def counting(traversals, repeats):
        calls.append(1)
        return _linear_timer(traversals, repeats)

    monkeypatch.setattr(cal, "_timed", counting)
    assert cal.cost_ratio(TRIANGLE) == pytest.approx(INTERSECTION / CELL_STEP)
    assert cal.cost_ratio(TRIANGLE) == pytest.approx(INTERSECTION / CELL_STEP)
    assert len(calls) == 1
    cached = json.loads(cal.cache_path().read_text())
    (entries,) = cached.values()
    assert entries["triangle"]["source"] == "measured" and entries["triangle"]["attempts"] == 1
    cal.cost_ratio(TRIANGLE, refresh=True)
    assert len(calls) == 2


def test_a_corrupt_cache_is_measured_again(monkeypatch, unpinned):
    monkeypatch.setattr(cal, "_timed", _linear_timer)
    cal.cache_path().parent.mkdir(parents=True)
    cal.cache_path().write_text("[1, 2")
    assert cal.cost_ratio(SPHERE) == pytest.approx(INTERSECTION / CELL_STEP)
    cal.cache_path().write_text(json.dumps(["not", "a", "mapping"]))
    assert cal.cost_ratio(SPHERE) == pytest.approx(INTERSECTION / CELL_STEP)


def test_the_environment_pins_the_ratio(monkeypatch, unpinned):
    monkeypatch.setattr(cal, "_timed", _noise_timer)
    monkeypatch.setenv(cal.RATIO_VARIABLE, "1.5")
    assert cal.cost_ratio(TRIANGLE) == 1.5 and cal.cost_ratio(SPHERE) == 1.5
    monkeypatch.setenv(cal.RATIO_VARIABLE, "triangle=3, sphere=0.5")
    assert cal.cost_ratio(TRIANGLE) == 3.0 and cal.cost_ratio(SPHERE) == 0.5
    assert cal.calibration(SPHERE)["source"] == "environment"
    for bad in ("fast", "-1", "triangle=2", "nan"):
        monkeypatch.setenv(cal.RATIO_VARIABLE, bad)
        with pytest.raises(ValueError, match=cal.RATIO_VARIABLE):
            cal.cost_ratio(SPHERE)
