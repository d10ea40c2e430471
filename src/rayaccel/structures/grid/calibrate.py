"""Measured costs of the grid cost model: one primitive test ``C_i`` and one cell step ``C_c``.

The optimal number of cells ``2 n C_i / C_c`` (see :mod:`.build_uniform`)
depends on how fast this machine tests a primitive relative to one DDA step,
inside a real traversal; timed apart (tests in a tight brute-force loop, steps
through an empty grid) they are measured outside the work they model.
:func:`calibrate` therefore measures them in place: a scene of 20,000 random
primitives of the kind is traced by 16,384 rays through grids of 1/2, 2, 8 and
32 cells per primitive; the counters give the cells visited and the tests run
in each, and a least-squares fit of the traced seconds against
``cells * C_c + tests * C_i + rays * C_ray`` yields both costs (``C_ray`` takes
up the per-ray set-up). Each time is the median of three runs. Results are cached as JSON in
``$XDG_CACHE_HOME/rayaccel/calibration.json`` (``~/.cache`` by default),
keyed by machine and Numba version; ``rayaccel calibrate`` re-measures.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import numba
import numpy as np

from ..._timing import median_seconds
from ...scene import SPHERE, TRIANGLE, Spheres, TriangleMesh

__all__ = ["calibrate", "cost_ratio", "cache_path"]

_KIND_NAMES = {TRIANGLE: "triangle", SPHERE: "sphere"}


def cache_path() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "rayaccel" / "calibration.json"


def _machine_key() -> str:
    return f"in-place fit|{platform.node()}|{platform.machine()}|{platform.processor()}|numba {numba.__version__}"


def _sample_scene(kind: int, n: int, rng) -> TriangleMesh | Spheres:
    if kind == SPHERE:
        return Spheres(rng.uniform(0.1, 0.9, (n, 3)), rng.uniform(0.01, 0.05, n))
    base = rng.uniform(0.1, 0.9, (n, 1, 3))
    corners = base + rng.normal(scale=0.05, size=(n, 3, 3))
    return TriangleMesh(corners.reshape(-1, 3), np.arange(3 * n).reshape(n, 3))


def _box_crossing_rays(n: int, rng):
    origins = rng.uniform(0.0, 1.0, (n, 3))
    origins[:, 0] = -0.5
    targets = rng.uniform(0.0, 1.0, (n, 3))
    targets[:, 0] = 1.5
    return origins, targets - origins


def calibrate(kind: int) -> dict:
    """Measure ``C_i`` and ``C_c`` in seconds for primitives of ``kind`` (see the module docstring)."""
    from ..registry import build

    rng = np.random.default_rng(0)
    scene = _sample_scene(kind, 20_000, rng)
    origins, directions = _box_crossing_rays(16_384, rng)
    rows, seconds = [], []
    for density in (0.5, 2.0, 8.0, 32.0):
        grid = build(scene, "grid", density=density)
        counters = grid.intersect(origins, directions, counters=True).counters
        rows.append([counters.nodes.sum(), counters.tests.sum(), len(origins)])
        seconds.append(median_seconds(lambda: grid.intersect(origins, directions), repeats=3))
    (cell_step, intersection, per_ray), *_ = np.linalg.lstsq(np.array(rows, float), np.array(seconds), rcond=None)
    if cell_step <= 0 or intersection <= 0:
        raise RuntimeError(f"grid cost calibration failed (C_c = {cell_step:.3g}, C_i = {intersection:.3g} s); "
                           "the machine may be too busy to time it: run `rayaccel calibrate` again")
    return {"intersection_seconds": float(intersection), "cell_step_seconds": float(cell_step),
            "ray_setup_seconds": float(per_ray), "ratio": float(intersection / cell_step)}


def cost_ratio(kind: int, refresh: bool = False) -> float:
    """``C_i / C_c`` for ``kind`` on this machine, from the cache or measured now."""
    path = cache_path()
    key = _machine_key()
    name = _KIND_NAMES[kind]
    cache = {}
    if path.exists():
        try:
            cache = json.loads(path.read_text())
        except (OSError, ValueError):
            cache = {}
    entry = cache.get(key, {}).get(name)
    if entry is None or refresh:
        entry = calibrate(kind)
        cache.setdefault(key, {})[name] = entry
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(cache, indent=2))
        except OSError:
            pass
    return float(entry["ratio"])
