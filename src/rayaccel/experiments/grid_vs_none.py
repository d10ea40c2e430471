"""The lecture's first table: a uniform grid against no acceleration at all.

Scenes are ``n`` random spheres in the unit cube (:func:`rayaccel.random_spheres`)
for n = 10, 100, ..., 1,000,000; the grid has 8n cells. Every row renders the
same image size from the same camera with the same light, through the same
renderer (:func:`rayaccel.render.render`: one primary ray per pixel, one shadow
ray per lit hit, shading), so both columns time the same work. The grid's time
includes its build.

Brute force costs n tests per ray, which for large n would take hours; there
a random subset of the pixels is rendered and the time is scaled up to all
pixels. Such figures are marked as extrapolated.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..rays import Camera
from ..render import default_lights, render
from ..scene import random_spheres
from ..structures.registry import build

__all__ = ["GridVsNoneRow", "run", "write_report"]

_BRUTE_FORCE_TEST_BUDGET = 4e8  # primitive tests allowed for a full brute-force render


@dataclass
class GridVsNoneRow:
    n: int
    grid_build_seconds: float
    grid_render_seconds: float
    none_seconds: float
    none_extrapolated: bool
    none_pixels: int
    on_cluster: bool = False

    @property
    def grid_seconds(self) -> float:
        return self.grid_build_seconds + self.grid_render_seconds

    @property
    def speedup(self) -> float:
        return self.none_seconds / self.grid_seconds


def _experiment_camera() -> Camera:
    return Camera.framing(np.zeros(3), np.ones(3), view=(0.35, 0.3, 1.0))


def _render(accel, camera, size, lights, pixels=None, client=None):
    if client is None:
        return render(accel, camera, size, size, lights, pixels=pixels)
    from ..distributed import render as render_tiles

    return render_tiles(accel, camera, size, size, lights, pixels=pixels, client=client)


def _time_brute_force(scene, camera, lights, size, rng, client=None) -> tuple[float, bool, int]:
    accel = build(scene, "none")
    n_pixels = size * size
    sample = int(min(n_pixels, max(256, _BRUTE_FORCE_TEST_BUDGET / (2 * len(scene)))))
    pixels = np.sort(rng.choice(n_pixels, sample, replace=False)) if sample < n_pixels else None
    start = time.perf_counter()
    _render(accel, camera, size, lights, pixels, client)
    seconds = time.perf_counter() - start
    return seconds * n_pixels / sample, sample < n_pixels, sample


def run(sizes=(10, 100, 1_000, 10_000, 100_000, 1_000_000), image_size: int = 512, seed: int = 0,
        progress=None, client=None, distribute_from: int = 100_000) -> list[GridVsNoneRow]:
    """Time grid (build + render) and brute force for each scene size; ``progress(i, total)``.

    With a ``distributed.Client``, scenes of ``distribute_from`` spheres or more render on its cluster."""
    camera = _experiment_camera()
    rng = np.random.default_rng(seed)
    warm_up = random_spheres(10, seed=seed)
    render(build(warm_up, "grid"), camera, 8, 8)
    _time_brute_force(warm_up, camera, default_lights(warm_up, camera), 8, rng)
    rows = []
    for index, n in enumerate(sizes):
        scene = random_spheres(n, seed=seed)
        lights = default_lights(scene, camera)
        start = time.perf_counter()
        grid = build(scene, "grid", density=8.0)
        build_seconds = time.perf_counter() - start
        remote = client if n >= distribute_from else None
        start = time.perf_counter()
        _render(grid, camera, image_size, lights, client=remote)
        render_seconds = time.perf_counter() - start
        none_seconds, extrapolated, pixels = _time_brute_force(scene, camera, lights, image_size, rng, remote)
        rows.append(GridVsNoneRow(n, build_seconds, render_seconds, none_seconds, extrapolated, pixels,
                                  remote is not None))
        if progress is not None:
            progress(index + 1, len(sizes))
    return rows


def write_report(rows: list[GridVsNoneRow], out_dir, image_size: int) -> tuple[Path, Path]:
    """Write ``grid-vs-none.md`` and the log-log plot ``grid-vs-none.png`` into ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [
        f"# Grid vs no grid: n random spheres in the unit cube, {image_size}x{image_size} pixels, one light",
        "",
        "Grid: 8n cells, time = build + render (primary and shadow rays, shading). "
        "No grid: brute force, the same render. `*` = a random subset of the pixels rendered and the time scaled up.",
        "",
        "| n | grid seconds (build + render) | grid build | no-grid seconds | speed-up |",
        "|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        mark = "*" if row.none_extrapolated else ""
        cluster = " (D)" if row.on_cluster else ""
        lines.append(f"| {row.n:,}{cluster} | {row.grid_seconds:.3f} | {row.grid_build_seconds:.3f} | "
                     f"{row.none_seconds:,.2f}{mark} | {row.speedup:,.{1 if row.speedup < 10 else 0}f}{mark} |")
    if any(row.on_cluster for row in rows):
        lines += ["", "(D): rendered in tiles on a Dask cluster; wall-clock seconds, sending the structures included."]
    if len(rows) >= 2:
        lines += ["", f"Grid time grows by {rows[-1].grid_seconds / rows[0].grid_seconds:.2f}x from "
                      f"n = {rows[0].n:,} to n = {rows[-1].n:,}."]
    table = out_dir / "grid-vs-none.md"
    table.write_text("\n".join(lines) + "\n")

    n = [row.n for row in rows]
    fig, ax = plt.subplots(figsize=(6, 4.2), dpi=120)
    ax.loglog(n, [row.grid_seconds for row in rows], "o-", label="grid, 8n cells (build + render)")
    exact = [row for row in rows if not row.none_extrapolated]
    extra = [row for row in rows if row.none_extrapolated]
    ax.loglog([r.n for r in rows], [r.none_seconds for r in rows], "-", color="C3", alpha=0.5)
    if exact:
        ax.loglog([r.n for r in exact], [r.none_seconds for r in exact], "s", color="C3", label="no grid (measured)")
    if extra:
        ax.loglog([r.n for r in extra], [r.none_seconds for r in extra], "s", color="C3", mfc="none",
                  label="no grid (extrapolated)")
    ax.set_xlabel("number of spheres n")
    ax.set_ylabel("seconds")
    ax.set_title(f"Grid vs no grid, {image_size}x{image_size} pixels")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    plot = out_dir / "grid-vs-none.png"
    fig.savefig(plot, bbox_inches="tight")
    plt.close(fig)
    return table, plot
