"""The lecture's "which BVH is better": every BVH builder on real scenes, measured.

For each scene and builder: build seconds, SAH cost (the expected cost
``C_t * sum_inner SA / SA_root + C_i * sum_leaves n SA / SA_root`` with the
builder's C_t and C_i), nodes, depth, measured nodes and primitive tests per
primary ray, and closest-hit and any-hit
throughput on primary (pinhole camera) and incoherent (random origins in the
scene box, uniform directions) rays. Every builder runs as published, without
the reinsertion pass ``bvh-binned`` applies by default (``reinsertion=False``).
Writes ``bvh.md``, a plot of build time against trace time and SAH cost, and
node-visit heatmaps of every builder on the first scene.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._timing import median_seconds
from ..catalog import load_scene
from ..render import default_camera, render, save_heatmap
from ..structures.registry import build, methods
from ._report import markdown_table, new_figure, save_figure

__all__ = ["DEFAULT_SCENES", "BuilderRow", "heatmap_path", "incoherent_rays", "run", "write_report"]

DEFAULT_SCENES = ("bunny", "buddha", "armadillo", "dragon-203k", "dragon", "spheres:100000")


@dataclass
class BuilderRow:
    scene: str
    method: str
    primitives: int
    build_seconds: float
    sah_cost: float
    nodes: int
    max_depth: int
    nodes_per_ray: float
    tests_per_ray: float
    primary_mrays: float
    primary_any_mrays: float
    incoherent_mrays: float
    incoherent_any_mrays: float


def incoherent_rays(scene, n: int, seed: int = 0):
    """Origins uniform in the scene's box, directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    origins = rng.uniform(b.scene_lo, b.scene_hi, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def _rate(accel, origins, directions, any_hit: bool) -> float:
    query = accel.occluded if any_hit else accel.intersect
    return len(origins) / median_seconds(lambda: query(origins, directions), repeats=3) / 1e6


def heatmap_path(heatmap_dir, scene_name: str, method: str) -> Path:
    """Where :func:`run` writes the nodes-visited heatmap of builder ``method`` on ``scene_name``."""
    return Path(heatmap_dir) / f"bvh-heatmap-{scene_name.replace(':', '-')}-{method}.png"


def run(scenes=DEFAULT_SCENES, builders=None, side: int = 512, heatmap_dir: Path | None = None,
        progress=None) -> list[BuilderRow]:
    """Measure every builder on every scene; ``progress(done, total)`` after each pair."""
    builders = builders or [m for m in methods() if m.startswith("bvh-")]
    warm_up = load_scene("spheres:16")
    for method in builders:  # compile (or load from Numba's cache) before timing
        build(warm_up, method, reinsertion=False).intersect(*incoherent_rays(warm_up, 4))
    rows = []
    total = len(scenes) * len(builders)
    for s, name in enumerate(scenes):
        scene = load_scene(name)
        camera = default_camera(scene)
        primary = camera.rays(side, side)
        incoherent = incoherent_rays(scene, side * side)
        for b, method in enumerate(builders):
            start = time.perf_counter()
            accel = build(scene, method, reinsertion=False)
            build_seconds = time.perf_counter() - start
            stats = accel.stats(*primary)
            rows.append(BuilderRow(
                name, method, len(scene), build_seconds, stats["sah_cost"], stats["nodes"], stats["max_depth"],
                stats["avg_nodes_per_ray"], stats["avg_intersections_per_ray"],
                _rate(accel, *primary, False), _rate(accel, *primary, True),
                _rate(accel, *incoherent, False), _rate(accel, *incoherent, True)))
            if heatmap_dir is not None and s == 0:
                result = render(accel, camera, side, side, shadows=False)
                save_heatmap(result.nodes, heatmap_path(heatmap_dir, name, method), "nodes visited",
                             f"{name}, {method}")
            if progress is not None:
                progress(s * len(builders) + b + 1, total)
    return rows


def write_report(rows: list[BuilderRow], out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    headers = ["scene", "builder", "triangles", "build s", "SAH cost", "nodes", "depth", "nodes/ray", "tests/ray",
               "primary Mrays/s", "primary any-hit", "incoherent Mrays/s", "incoherent any-hit"]
    table = [[r.scene, r.method, f"{r.primitives:,}", f"{r.build_seconds:.3f}", f"{r.sah_cost:.1f}", f"{r.nodes:,}",
              r.max_depth, f"{r.nodes_per_ray:.1f}", f"{r.tests_per_ray:.2f}", f"{r.primary_mrays:.2f}",
              f"{r.primary_any_mrays:.2f}", f"{r.incoherent_mrays:.2f}", f"{r.incoherent_any_mrays:.2f}"]
             for r in rows]
    lines = [f"# Which BVH is better? Every builder, {side}x{side} primary and as many incoherent rays", "",
             "SAH cost: expected cost per ray that hits the root, C_t = 2, C_i = 1 (the defaults of the box BVHs). "
             "Nodes (eight-wide, as walked) and tests per ray: "
             "measured on the primary rays, closest hit. Throughput: median of 3, all threads.", ""]
    lines += markdown_table(headers, table, align_right_from=2)
    path = out_dir / "bvh.md"
    path.write_text("\n".join(lines) + "\n")

    fig, (left, right) = new_figure(2)
    for i, method in enumerate(sorted({r.method for r in rows})):
        mine = [r for r in rows if r.method == method]
        left.scatter([r.build_seconds for r in mine], [1.0 / r.primary_mrays for r in mine], label=method,
                     color=f"C{i}")
        right.scatter([r.sah_cost for r in mine], [1.0 / r.incoherent_mrays for r in mine], label=method,
                      color=f"C{i}")
    left.set(xscale="log", yscale="log", xlabel="build seconds", ylabel="seconds per million primary rays",
             title="build time against trace time")
    right.set(xscale="log", yscale="log", xlabel="SAH cost", ylabel="seconds per million incoherent rays",
              title="SAH cost predicts trace time")
    for ax in (left, right):
        ax.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=8)
    plot = save_figure(fig, out_dir / "bvh.png")
    return path, plot
