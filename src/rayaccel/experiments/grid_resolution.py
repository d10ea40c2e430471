"""Grid resolution against the cost model: sweep the cells per primitive and find the fastest.

A grid with R cells over n primitives costs about ``C_c R^(1/3) + C_i n / R^(2/3)``
per ray, least at ``R = 2 n C_i / C_c`` (see
:mod:`rayaccel.structures.grid.build_uniform`). This experiment builds grids
with densities from 1/4 to 64 cells per primitive, times closest-hit primary
rays (and the build), and marks the cost model's optimum, with ``C_i`` and
``C_c`` calibrated on this machine (:mod:`rayaccel.structures.grid.calibrate`)
and the calibration's relative uncertainty as a band around it, the fastest
measured density, and the lecture's 8 cells per primitive on the measured
curve, so that a reader sees whether ``2 n C_i / C_c`` lands where the time
is lowest.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .._timing import median_seconds
from ..catalog import load_scene
from ..render import default_camera
from ..structures.grid.calibrate import calibration
from ..structures.registry import build
from ._report import markdown_table, new_figure, save_figure

__all__ = ["DENSITIES", "ResolutionRow", "run", "write_report"]

DENSITIES = (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)


@dataclass
class ResolutionRow:
    scene: str
    density: float
    cells: int
    build_seconds: float
    trace_seconds: float
    cells_per_ray: float
    tests_per_ray: float
    model_density: float
    model_uncertainty: float


def run(scenes=("bunny", "spheres:100000"), densities=DENSITIES, side: int = 512, progress=None) -> list[ResolutionRow]:
    rows = []
    total = len(scenes) * len(densities)
    for s, name in enumerate(scenes):
        scene = load_scene(name)
        rays = default_camera(scene).rays(side, side)
        model = calibration(scene.kind)
        model_density = 2.0 * model["ratio"]
        for d, density in enumerate(densities):
            grid = build(scene, "grid", density=density)
            build_seconds = median_seconds(lambda: build(scene, "grid", density=density), repeats=3)
            trace = median_seconds(lambda: grid.intersect(*rays), repeats=3)
            counters = grid.intersect(*rays, counters=True).counters
            rows.append(ResolutionRow(name, density, grid.grid.n_cells, build_seconds, trace,
                                      float(counters.nodes.mean()), float(counters.tests.mean()), model_density,
                                      float(model["uncertainty"])))
            if progress is not None:
                progress(s * len(densities) + d + 1, total)
    return rows


def write_report(rows: list[ResolutionRow], out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [f"# Grid resolution against the cost model ({side}x{side} closest-hit primary rays)", ""]
    scenes = list(dict.fromkeys(r.scene for r in rows))
    for name in scenes:
        mine = [r for r in rows if r.scene == name]
        best = min(mine, key=lambda r: r.build_seconds + r.trace_seconds)
        fastest_trace = min(mine, key=lambda r: r.trace_seconds)
        lines += [f"**{name}**: cost model optimum {mine[0].model_density:.1f} "
                  f"+- {mine[0].model_uncertainty:.0%} cells per primitive (R = 2 n C_i / C_c with C_i / C_c "
                  f"calibrated here); fastest trace measured at density {fastest_trace.density:g}, "
                  f"fastest build + trace at {best.density:g}.", ""]
    headers = ["scene", "cells per primitive", "cells", "build s", "trace s", "build + trace s", "cells/ray",
               "tests/ray"]
    table = [[r.scene, f"{r.density:g}", f"{r.cells:,}", f"{r.build_seconds:.4f}", f"{r.trace_seconds:.4f}",
              f"{r.build_seconds + r.trace_seconds:.4f}", f"{r.cells_per_ray:.1f}", f"{r.tests_per_ray:.2f}"]
             for r in rows]
    lines += markdown_table(headers, table, align_right_from=1)
    path = out_dir / "grid-resolution.md"
    path.write_text("\n".join(lines) + "\n")
    fig, (ax,) = new_figure(1)
    for i, name in enumerate(scenes):
        mine = [r for r in rows if r.scene == name]
        ax.loglog([r.density for r in mine], [r.build_seconds + r.trace_seconds for r in mine], "o-", color=f"C{i}",
                  label=f"{name}: build + trace")
        ax.loglog([r.density for r in mine], [r.trace_seconds for r in mine], ":", color=f"C{i}",
                  label=f"{name}: trace")
        model, spread = mine[0].model_density, mine[0].model_uncertainty
        ax.axvline(model, color=f"C{i}", alpha=0.6, linestyle="--",
                   label=f"{name}: cost model 2 C_i / C_c = {model:.1f} +- {spread:.0%}")
        if spread > 0:
            ax.axvspan(model * (1 - spread), model * (1 + spread), color=f"C{i}", alpha=0.15)
        fastest = min(mine, key=lambda r: r.trace_seconds)
        ax.plot([fastest.density], [fastest.trace_seconds], "*", color=f"C{i}", markersize=12,
                label=f"{name}: fastest trace measured")
    ax.axvline(8.0, color="grey", alpha=0.4, label="lecture: 8 cells per primitive")
    ax.set(xlabel="cells per primitive", ylabel="seconds", title="grid resolution against the cost model")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    return path, save_figure(fig, out_dir / "grid-resolution.png")
