"""The lecture's kd-tree statistics table, for the kd-tree or any other structure.

One column per scene, the lecture's rows exactly: triangles, leaf nodes,
non-empty leaf nodes, construction time, average triangles per non-empty leaf,
the expected traversal steps, leaves visited, intersections and cost per ray
from surface areas (:mod:`rayaccel.stats`; for rays that hit the root box), the
render time of one frame (primary rays plus one shadow ray per hit), and the
measured average nodes and intersections per primary ray. The default scenes
are the scanned meshes and the procedural forest scenes of
:mod:`rayaccel.procedural`. Writes ``kdtree-table-METHOD.md`` and a plot of
build and render time per scene.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..catalog import load_scene
from ..render import default_camera, render, warm_up
from ..structures.registry import build
from ._report import build_and_render_bars, markdown_table

__all__ = ["DEFAULT_SCENES", "ROWS", "run", "write_report"]

DEFAULT_SCENES = ("dragon", "dragon-203k", "armadillo", "buddha", "bunny", "forest", "forest-large-chair",
                  "forest-small-chair")

# (row label, statistic key, format)
ROWS = (
    ("# triangles", "primitives", "{:,}"),
    ("# leaf nodes", "leaves", "{:,}"),
    ("# non-empty leaf nodes", "nonempty_leaves", "{:,}"),
    ("construction time", "build_seconds", "{:.3f} s"),
    ("avg # triangles / non-empty leaf node", "avg_prims_per_nonempty_leaf", "{:.2f}"),
    ("exp # traversal steps", "expected_traversal_steps", "{:.1f}"),
    ("exp # leaves visited", "expected_leaves_visited", "{:.2f}"),
    ("exp # intersections", "expected_intersections", "{:.2f}"),
    ("exp cost", "expected_cost", "{:.1f}"),
    ("render time", "render_seconds", "{:.3f} s"),
    ("avg # nodes / ray", "avg_nodes_per_ray", "{:.1f}"),
    ("avg # intersections / ray", "avg_intersections_per_ray", "{:.2f}"),
)


def measure(name: str, scene, method: str, side: int) -> tuple[dict, object]:
    """Statistics of ``method`` on one scene, with the render time of a ``side`` x ``side`` frame;
    returns them and the rendered frame."""
    start = time.perf_counter()
    accel = build(scene, method)
    build_seconds = time.perf_counter() - start
    camera = default_camera(scene)
    stats = accel.stats(*camera.rays(side, side))
    stats["build_seconds"] = build_seconds
    result = render(accel, camera, side, side)
    stats["render_seconds"] = result.trace_seconds
    stats["scene"] = name
    return stats, result


def run(scenes=DEFAULT_SCENES, method: str = "kdtree", side: int = 512, progress=None) -> list[dict]:
    """One statistics dict per scene; ``progress(done, total)`` after each."""
    warm_up([method])
    columns = []
    for s, name in enumerate(scenes):
        columns.append(measure(name, load_scene(name), method, side)[0])
        if progress is not None:
            progress(s + 1, len(scenes))
    return columns


def write_report(columns: list[dict], method: str, out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    headers = [""] + [c["scene"] for c in columns]
    table = [[label] + [fmt.format(c[key]) for c in columns] for label, key, fmt in ROWS]
    lines = [f"# The kd-tree table for `{method}`", "",
             f"Expected figures per ray that hits the root box, from surface areas; render time: one {side}x{side} "
             "frame, primary rays plus one shadow ray per hit and light; nodes and intersections per ray: measured on "
             "the primary rays (closest hit). Grids count cells as nodes.", ""]
    lines += markdown_table(headers, table, align_right_from=1)
    path = out_dir / f"kdtree-table-{method}.md"
    path.write_text("\n".join(lines) + "\n")
    return path, build_and_render_bars([c["scene"] for c in columns], [c["build_seconds"] for c in columns],
                                       [c["render_seconds"] for c in columns], method, side,
                                       out_dir / f"kdtree-table-{method}.png")
