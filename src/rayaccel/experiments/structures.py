"""Every structure side by side on one scene: build, expected cost, render time, work per ray.

For each method but brute force: construction time, the expected cost per ray
from surface areas (the SAH cost for trees; for grids every cell entered
counts as a step), the render time of one frame (primary plus shadow rays),
the measured nodes (or cells) and intersections per primary ray, and a
heatmap of the nodes visited per pixel. Writes ``structures-SCENE.md``, a bar
chart, and the heatmaps.
"""

from __future__ import annotations

from pathlib import Path

from ..catalog import load_scene
from ..render import save_heatmap, save_png, warm_up
from ..structures.registry import methods as all_methods
from ._report import build_and_render_bars, markdown_table
from .kdtree_table import measure

__all__ = ["image_paths", "run", "write_report"]


def image_paths(out_dir, scene_name: str, method: str) -> tuple[Path, Path]:
    """Where :func:`run` writes the render and the nodes-visited heatmap of ``method`` on ``scene_name``."""
    stem = Path(out_dir) / f"structures-{scene_name.replace(':', '-')}-{method}"
    return stem.with_suffix(".png"), stem.with_name(stem.name + "-nodes.png")


def run(scene_name: str = "forest-small-chair", methods=None, side: int = 512, out_dir=None,
        progress=None) -> list[dict]:
    """Measure every method on one scene, writing its image and heatmap into ``out_dir``."""
    methods = methods or [m for m in all_methods() if m != "none"]
    scene = load_scene(scene_name)
    warm_up(methods, [scene.kind])
    rows = []
    for k, method in enumerate(methods):
        stats, result = measure(scene_name, scene, method, side)
        if out_dir is not None:
            image, heatmap = image_paths(out_dir, scene_name, method)
            save_png(result.image, image)
            save_heatmap(result.nodes, heatmap, "nodes or cells visited", f"{scene_name}, {method}")
        rows.append(stats)
        if progress is not None:
            progress(k + 1, len(methods))
    return rows


def write_report(rows: list[dict], out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = rows[0]["scene"]
    headers = ["method", "build s", "expected cost", "render s", "nodes/ray", "tests/ray", "references",
               "bytes"]
    table = [[r["method"], f"{r['build_seconds']:.3f}", f"{r['expected_cost']:.1f}", f"{r['render_seconds']:.3f}",
              f"{r['avg_nodes_per_ray']:.1f}", f"{r['avg_intersections_per_ray']:.2f}", f"{r['references']:,}",
              f"{r['bytes']:,}"] for r in rows]
    lines = [f"# Every structure on `{scene}` ({rows[0]['primitives']:,} primitives)", "",
             f"Expected cost per ray that hits the root box, from surface areas, with each method's own C_t and C_i "
             f"(grids: every cell entered is a step). Render: one {side}x{side} frame with shadow rays. Nodes and "
             f"tests per ray: measured on the primary rays. Heatmaps: `structures-{scene}-METHOD-nodes.png`.", ""]
    lines += markdown_table(headers, table, align_right_from=1)
    path = out_dir / f"structures-{scene.replace(':', '-')}.md"
    path.write_text("\n".join(lines) + "\n")
    return path, build_and_render_bars([r["method"] for r in rows], [r["build_seconds"] for r in rows],
                                       [r["render_seconds"] for r in rows], scene, side,
                                       out_dir / f"structures-{scene.replace(':', '-')}.png")
