"""Measured costs of the grid cost model: one primitive test ``C_i`` and one cell step ``C_c``.

The optimal number of cells ``2 n C_i / C_c`` (see :mod:`.build_uniform`)
depends on how fast this machine tests a primitive relative to one DDA step
of the real traversal (:func:`.traverse.grid_closest_kernel`). Fitting the time
of whole traversals against their cell and test counts is ill-posed: across
grid densities the two counts move against each other, so timing noise decides
the sign of the fitted costs. Each cost is therefore measured on its own, in
the real kernel, as the slope of time per ray against a count that nothing
else changes:

* ``C_c``: rays cross a grid whose cells along their paths are empty (the
  primitives lie in two thin slabs the rays stay clear of) at 8 to 128 cells
  per axis; a ray steps through about as many cells and tests nothing.
* ``C_i``: rays cross a grid of a single cell holding m = 16 to 1,024
  primitives of the kind; every ray tests all m (mailbox stamps included).

The per-ray set-up (clipping to the grid box, the first cell, the shear of the
triangle test) is the same at every point of a sweep, so it drops out of the
slope; it is reported as the intercept. Each point is the fastest of 15
timings of about a millisecond (a busy machine only ever adds time), taken
round-robin over both sweeps, so that a slow spell touches every point of
both alike, and on one thread, so that no thread waits on another one that
was descheduled. Slopes are Theil-Sen estimates (the median of the slopes between all
pairs of points; Sen 1968), which one disturbed point cannot move, and the
ratio's relative uncertainty is the spread of the ratio over bootstrap
resamples of the points. A fit whose slope is not positive or whose
uncertainty exceeds :data:`MAX_UNCERTAINTY` is repeated; after
:data:`ATTEMPTS` poor fits the ratio falls back to :data:`DEFAULT_RATIOS`
with a warning.

Results are cached as JSON in ``$XDG_CACHE_HOME/rayaccel/calibration.json``
(``~/.cache`` by default), keyed by machine and Numba version; ``rayaccel
calibrate`` re-measures. The environment variable
:data:`RATIO_VARIABLE` fixes the ratio instead (one number for every kind,
or ``triangle=0.4,sphere=0.25``), so that runs which must not depend on a
timing, such as the tests, can pin it.
"""

from __future__ import annotations

import json
import os
import platform
import time
import warnings
from pathlib import Path

import numba
import numpy as np

from ..._jit import set_threads, thread_count
from ...rays import WORK_COLUMNS
from ...scene import SPHERE, TRIANGLE, Spheres, TriangleMesh
from ..actions import nearest_hit
from .build_uniform import build_grid, grid_box
from .traverse import grid_closest_kernel

__all__ = ["calibrate", "calibration", "cost_ratio", "cache_path", "fit_slope", "DEFAULT_RATIOS",
           "MAX_UNCERTAINTY", "ATTEMPTS", "RATIO_VARIABLE"]

KIND_NAMES = {TRIANGLE: "triangle", SPHERE: "sphere"}
# C_i / C_c measured on a 2-core x86-64 VM (benchmarks/bench_calibration.py, medians of 20 calibrations).
DEFAULT_RATIOS = {TRIANGLE: 2.3, SPHERE: 0.9}
MAX_UNCERTAINTY = 0.15
ATTEMPTS = 3
RATIO_VARIABLE = "RAYACCEL_GRID_COST_RATIO"

_STEP_RESOLUTIONS = (8, 12, 16, 20, 24, 32, 40, 48, 64)
_TEST_COUNTS = (16, 32, 64, 128, 256, 384, 512, 768, 1024)
_STEP_RAYS = 2_048
_TEST_RAYS = 128
_REPEATS = 15
_BOOTSTRAP = 200
_warned: set[str] = set()


def cache_path() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "rayaccel" / "calibration.json"


def _machine_key() -> str:
    return f"isolated slopes|{platform.node()}|{platform.machine()}|{platform.processor()}|numba {numba.__version__}"


def _primitives(kind: int, centers: np.ndarray, size: float, rng) -> TriangleMesh | Spheres:
    """Small primitives of ``kind`` around ``centers``: spheres of radius up to ``size``,
    or triangles whose corners lie within about ``size`` of the centre."""
    n = len(centers)
    if kind == SPHERE:
        return Spheres(centers, rng.uniform(0.3 * size, size, n))
    corners = centers[:, None, :] + rng.uniform(-size, size, (n, 3, 3))
    return TriangleMesh(corners.reshape(-1, 3), np.arange(3 * n).reshape(n, 3))


def _rays_across(n: int, band: tuple[float, float], rng) -> tuple[np.ndarray, np.ndarray]:
    """Rays from x = -0.5 to x = 1.5 whose y and z stay inside ``band`` over the unit cube."""
    origins = rng.uniform(*band, (n, 3))
    targets = rng.uniform(*band, (n, 3))
    origins[:, 0] = -0.5
    targets[:, 0] = 1.5
    return origins, targets - origins


class _Traversal:
    """One grid over ``scene`` and a ray set, traced by the real kernel: counted once, timed on demand."""

    def __init__(self, scene, res, origins, directions):
        bounds = scene.bounds()
        lo, hi = grid_box(bounds.scene_lo, bounds.scene_hi)
        self.grid = build_grid(bounds, lo, hi, scene.kind, scene.geometry, np.asarray(res), False)
        self.scene = scene
        n = len(origins)
        self.rays = (origins, directions, np.zeros(n), np.full(n, np.inf), np.arange(n, dtype=np.int64))
        self.mailbox = np.full((numba.config.NUMBA_NUM_THREADS, len(scene)), -1, dtype=np.int32)
        self.stamp = 0
        work = self._run(np.zeros((n, WORK_COLUMNS), dtype=np.int64))
        self.cells_per_ray = float(work[:, 0].mean())
        self.tests_per_ray = float(work[:, 1].mean())

    def _run(self, work):
        n = len(self.rays[0])
        g = self.grid
        grid_closest_kernel(0, n, 0, g.lo, g.hi, g.res, g.cell_size, g.cell_first, g.cell_prims, self.scene.kind,
                            self.scene.geometry, *self.rays, False, self.mailbox, self.stamp,
                            nearest_hit(np.full(n, np.inf), np.full(n, -1, dtype=np.int64), np.zeros(n), np.zeros(n)),
                            work)
        self.stamp += n
        return work

    def seconds_per_ray(self) -> float:
        start = time.perf_counter()
        self._run(None)
        return (time.perf_counter() - start) / len(self.rays[0])


def _timed(traversals: list[_Traversal], repeats: int) -> np.ndarray:
    """Fastest seconds per ray of each traversal over ``repeats`` round-robin passes."""
    for traversal in traversals:
        traversal.seconds_per_ray()
    seconds = np.array([[t.seconds_per_ray() for t in traversals] for _ in range(repeats)])
    return seconds.min(axis=0)


def fit_slope(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Theil-Sen line through the points: ``(slope, intercept)``, the median of the pairwise
    slopes and the median of ``y - slope * x``."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    i, j = np.triu_indices(len(x), k=1)
    distinct = x[j] != x[i]
    if not distinct.any():
        return float("nan"), float("nan")
    slope = float(np.median((y[j] - y[i])[distinct] / (x[j] - x[i])[distinct]))
    return slope, float(np.median(y - slope * x))


def _bootstrap_spread(step_x, step_y, test_x, test_y, rng) -> float:
    """Relative standard deviation of ``C_i / C_c`` over bootstrap resamples of the points."""
    ratios = []
    for _ in range(_BOOTSTRAP):
        s = rng.integers(0, len(step_x), len(step_x))
        t = rng.integers(0, len(test_x), len(test_x))
        cell_step = fit_slope(step_x[s], step_y[s])[0]
        intersection = fit_slope(test_x[t], test_y[t])[0]
        if cell_step > 0 and intersection > 0:
            ratios.append(intersection / cell_step)
    if len(ratios) < _BOOTSTRAP // 2:
        return float("inf")
    ratios = np.array(ratios)
    return float(ratios.std() / np.median(ratios))


def _step_traversals(kind: int, rng) -> list[_Traversal]:
    n = 2_000
    centers = rng.uniform(0.0, 1.0, (n, 3))
    centers[:, 1] = np.where(np.arange(n) % 2 == 0, rng.uniform(0.0, 0.03, n), rng.uniform(0.97, 1.0, n))
    scene = _primitives(kind, centers, 0.01, rng)
    rays = _rays_across(_STEP_RAYS, (0.2, 0.8), rng)
    return [_Traversal(scene, (r, r, r), *rays) for r in _STEP_RESOLUTIONS]


def _test_traversals(kind: int, rng) -> list[_Traversal]:
    rays = _rays_across(_TEST_RAYS, (0.1, 0.9), rng)
    traversals = []
    for m in _TEST_COUNTS:
        centers = rng.uniform(0.0, 1.0, (m, 3))
        centers[:2] = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
        traversals.append(_Traversal(_primitives(kind, centers, 0.05, rng), (1, 1, 1), *rays))
    return traversals


def calibrate(kind: int, seed: int = 0) -> dict:
    """Measure ``C_c`` and ``C_i`` in seconds for primitives of ``kind`` once (see the module
    docstring): the costs, the per-ray set-up, ``ratio = C_i / C_c`` and its relative
    ``uncertainty``; ``ok`` says whether both slopes are positive and the uncertainty is at
    most :data:`MAX_UNCERTAINTY`."""
    rng = np.random.default_rng(seed)
    steps = _step_traversals(kind, rng)
    tests = _test_traversals(kind, rng)
    threads = thread_count()
    set_threads(1)
    try:
        seconds = _timed(steps + tests, _REPEATS)
    finally:
        set_threads(threads)
    step_x = np.array([t.cells_per_ray for t in steps])
    test_x = np.array([t.tests_per_ray for t in tests])
    step_seconds, test_seconds = seconds[:len(steps)], seconds[len(steps):]
    cell_step, setup = fit_slope(step_x, step_seconds)
    intersection, _ = fit_slope(test_x, test_seconds)
    positive = cell_step > 0 and intersection > 0
    ratio = intersection / cell_step if positive else float("nan")
    uncertainty = _bootstrap_spread(step_x, step_seconds, test_x, test_seconds, rng) if positive else float("inf")
    return {"intersection_seconds": float(intersection), "cell_step_seconds": float(cell_step),
            "ray_setup_seconds": float(setup), "ratio": float(ratio), "uncertainty": uncertainty,
            "ok": bool(positive and uncertainty <= MAX_UNCERTAINTY)}


def _measure(kind: int) -> dict:
    """:func:`calibrate` until a fit is good, at most :data:`ATTEMPTS` times; the default ratio
    of the kind, with a warning, when none is."""
    for attempt in range(ATTEMPTS):
        entry = calibrate(kind, seed=attempt)
        entry["attempts"] = attempt + 1
        if entry["ok"]:
            entry["source"] = "measured"
            return entry
    name = KIND_NAMES[kind]
    warnings.warn(f"the grid cost calibration for {name}s stayed poor after {ATTEMPTS} attempts (last: C_i / C_c = "
                  f"{entry['ratio']:.3g} +- {entry['uncertainty']:.0%}), probably because the machine is busy; "
                  f"using the default {DEFAULT_RATIOS[kind]}. Run `rayaccel calibrate` on a quieter machine to "
                  "measure it again.", RuntimeWarning, stacklevel=4)
    return {**entry, "ratio": DEFAULT_RATIOS[kind], "source": "default"}


def _from_environment(kind: int) -> float | None:
    text = os.environ.get(RATIO_VARIABLE, "").strip()
    if not text:
        return None
    try:
        if "=" not in text:
            value = float(text)
        else:
            values = {key.strip(): value for key, value in (item.split("=", 1) for item in text.split(","))}
            value = float(values[KIND_NAMES[kind]])
    except (KeyError, ValueError):
        raise ValueError(f"{RATIO_VARIABLE} must be a number or 'triangle=R,sphere=R', got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{RATIO_VARIABLE} must be positive, got {text!r}")
    return value


def calibration(kind: int, refresh: bool = False) -> dict:
    """The calibration in force for ``kind``: from :data:`RATIO_VARIABLE`, from the cache, or
    measured now (and cached); ``source`` says which (``"environment"``, ``"measured"`` or
    ``"default"``)."""
    fixed = _from_environment(kind)
    if fixed is not None and not refresh:
        return {"ratio": fixed, "uncertainty": 0.0, "source": "environment"}
    path = cache_path()
    key = _machine_key()
    name = KIND_NAMES[kind]
    cache = {}
    if path.exists():
        try:
            cache = json.loads(path.read_text())
        except (OSError, ValueError):
            cache = {}
    entry = cache.get(key, {}).get(name) if isinstance(cache, dict) else None
    if not isinstance(entry, dict) or not isinstance(entry.get("ratio"), (int, float)) or refresh:
        entry = _measure(kind)
        cache = cache if isinstance(cache, dict) else {}
        cache.setdefault(key, {})[name] = entry
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(cache, indent=2))
        except OSError:
            pass
    elif entry.get("source") == "default" and name not in _warned:
        _warned.add(name)
        warnings.warn(f"the grid cost ratio for {name}s is the default {entry['ratio']} (calibration failed earlier); "
                      "run `rayaccel calibrate` to measure it", RuntimeWarning, stacklevel=3)
    return entry


def cost_ratio(kind: int, refresh: bool = False) -> float:
    """``C_i / C_c`` for ``kind`` on this machine (see :func:`calibration`)."""
    return float(calibration(kind, refresh)["ratio"])
