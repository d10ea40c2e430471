"""The lecture's sphere table on this machine, and start-up costs.

1. n random spheres in the unit cube, grid with 8n cells: build + 512x512
   primary rays + one shadow ray per lit hit (the renderer's full frame, with
   shading), median of 5, for n = 1,000 ... 1,000,000; the growth factor from
   1,000 to 1,000,000 (the lecture: 1.9, and 5.2 s at n = 1,000,000).
2. ``import rayaccel`` time, and the first query's time with Numba's cache
   cold (an empty cache folder: everything compiles) and warm.

    python benchmarks/bench_lecture.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from rich.console import Console
from rich.table import Table

import rayaccel as ra
from rayaccel.experiments.grid_vs_none import _experiment_camera
from rayaccel.render import default_lights, render

FIRST_CALL = (
    "import time; t0 = time.perf_counter(); import rayaccel as ra; t1 = time.perf_counter(); "
    "g = ra.build(ra.random_spheres(100), 'grid'); g.intersect([[0.5, 0.5, -1.0]], [[0, 0, 1.0]]); "
    "g.occluded([[0.5, 0.5, -1.0]], [[0, 0, 1.0]]); "
    "print(t1 - t0, time.perf_counter() - t1)"
)


def frame_seconds(n: int, camera, repeats: int = 5) -> tuple[float, float, float]:
    scene = ra.random_spheres(n, seed=0)
    lights = default_lights(scene, camera)
    totals, builds, traces = [], [], []
    render(ra.build(scene, "grid"), camera, 64, 64, lights)
    for _ in range(repeats):
        start = time.perf_counter()
        grid = ra.build(scene, "grid", density=8.0)
        built = time.perf_counter()
        result = render(grid, camera, 512, 512, lights)
        totals.append(time.perf_counter() - start)
        builds.append(built - start)
        traces.append(result.trace_seconds)
    return float(np.median(totals)), float(np.median(builds)), float(np.median(traces))


def start_up(cache_dir: str) -> tuple[float, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, "-c", FIRST_CALL], env=env, capture_output=True, text=True, check=True)
    import_seconds, first_call = (float(x) for x in out.stdout.split())
    return import_seconds, first_call


def main() -> None:
    console = Console(width=160)
    camera = _experiment_camera()
    table = Table(title="random spheres, grid 8n cells, 512x512 primary + shadow rays (median of 5)")
    for column in ("n", "frame s (build + render)", "build s", "ray tracing s", "vs n = 1,000"):
        table.add_column(column, justify="right")
    base = None
    for n in (1_000, 10_000, 100_000, 1_000_000):
        total, build, trace = frame_seconds(n, camera)
        base = base or total
        table.add_row(f"{n:,}", f"{total:.3f}", f"{build:.3f}", f"{trace:.3f}", f"{total / base:.2f}x")
    console.print(table)

    with tempfile.TemporaryDirectory() as cache:
        import_cold, cold = start_up(cache)
        import_warm, warm = start_up(cache)
    console.print(f"import rayaccel: {import_warm:.2f} s; first build + queries: {cold:.1f} s with a cold Numba "
                  f"cache (compiling), {warm:.2f} s with a warm one")


if __name__ == "__main__":
    main()
