"""Measured costs of the grid cost model: one primitive test ``C_i`` and one cell step ``C_c``.

The optimal number of cells ``2 n C_i / C_c`` (see :mod:`.build_uniform`)
depends on how fast this machine tests a primitive relative to one DDA step.
:func:`calibrate` times both with the real kernels:

* ``C_i``: brute force over 256 random primitives of the kind, seconds per test;
* ``C_c``: rays crossing an almost empty 64^3 grid from face to face, seconds
  per cell visited (the counters give the number of cells).

Each figure is the median of five runs. Results are cached as JSON in
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
    return f"{platform.node()}|{platform.machine()}|{platform.processor()}|numba {numba.__version__}"


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
    """Measure ``C_i`` and ``C_c`` in seconds for primitives of ``kind``."""
    from ..registry import build

    rng = np.random.default_rng(0)
    scene = _sample_scene(kind, 256, rng)
    origins, directions = _box_crossing_rays(4096, rng)
    brute = build(scene, "none")
    seconds = median_seconds(lambda: brute.intersect(origins, directions))
    intersection = seconds / (len(origins) * len(scene))

    corner = _sample_scene(kind, 1, rng)
    grid = build(corner, "grid", resolution=64)
    lo, hi = grid.grid.lo, grid.grid.hi
    origins = lo + (hi - lo) * np.column_stack([np.full(4096, -0.5), rng.uniform(0, 1, (4096, 2))])
    targets = lo + (hi - lo) * np.column_stack([np.full(4096, 1.5), rng.uniform(0, 1, (4096, 2))])
    directions = targets - origins
    cells = grid.intersect(origins, directions, counters=True).counters.nodes.sum()
    seconds = median_seconds(lambda: grid.intersect(origins, directions))
    cell_step = seconds / cells
    return {"intersection_seconds": intersection, "cell_step_seconds": cell_step,
            "ratio": intersection / cell_step}


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
