"""Leaf size sweep for the kd-tree and the BVH ("often between 2 and 8", says the lecture).

The kd-tree's ``leaf_size`` (nodes with at most this many primitives are not
split; the SAH may stop earlier) and ``bvh-binned``'s ``max_leaf_size`` (the
largest leaf) are swept over 1 to 32 on each scene; for every setting the
build time, expected cost, time of closest-hit primary rays, and measured
nodes and tests per ray. Writes ``leaf-size.md`` and a plot of trace time
against leaf size.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .._timing import median_seconds
from ..catalog import load_scene
from ..render import default_camera, warm_up
from ..structures.registry import build
from ._report import markdown_table, new_figure, save_figure

__all__ = ["LEAF_SIZES", "SWEPT", "LeafSizeRow", "run", "write_report"]

LEAF_SIZES = (1, 2, 4, 8, 12, 16, 32)
"""The sizes swept: the lecture's range, the kd-tree's default (12) and the BVH's (4) among them."""
SWEPT = {"kdtree": "leaf_size", "bvh-binned": "max_leaf_size"}


@dataclass
class LeafSizeRow:
    scene: str
    method: str
    leaf_size: int
    build_seconds: float
    expected_cost: float
    trace_seconds: float
    nodes_per_ray: float
    tests_per_ray: float


def run(scenes=("bunny", "dragon-203k"), leaf_sizes=LEAF_SIZES, side: int = 512, progress=None) -> list[LeafSizeRow]:
    loaded = [(name, load_scene(name)) for name in scenes]
    warm_up(list(SWEPT), list(dict.fromkeys(scene.kind for _, scene in loaded)))
    rows = []
    total = len(scenes) * len(SWEPT) * len(leaf_sizes)
    for name, scene in loaded:
        rays = default_camera(scene).rays(side, side)
        for method, option in SWEPT.items():
            for size in leaf_sizes:
                accel = build(scene, method, **{option: size})
                stats = accel.stats(*rays)
                trace = median_seconds(lambda: accel.intersect(*rays), repeats=3)
                rows.append(LeafSizeRow(name, method, size, accel.build_seconds, stats["expected_cost"], trace,
                                        stats["avg_nodes_per_ray"], stats["avg_intersections_per_ray"]))
                if progress is not None:
                    progress(len(rows), total)
    return rows


def write_report(rows: list[LeafSizeRow], out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    headers = ["scene", "method", "leaf size", "build s", "expected cost", "trace s", "nodes/ray", "tests/ray"]
    table = [[r.scene, r.method, r.leaf_size, f"{r.build_seconds:.3f}", f"{r.expected_cost:.1f}",
              f"{r.trace_seconds:.4f}", f"{r.nodes_per_ray:.1f}", f"{r.tests_per_ray:.2f}"] for r in rows]
    lines = [f"# Leaf size: kd-tree `leaf_size` and bvh-binned `max_leaf_size` ({side}x{side} primary rays)", ""]
    for (name, method) in dict.fromkeys((r.scene, r.method) for r in rows):
        best = min((r for r in rows if r.scene == name and r.method == method), key=lambda r: r.trace_seconds)
        lines.append(f"- {name}, {method}: fastest tracing at leaf size {best.leaf_size}")
    lines.append("")
    lines += markdown_table(headers, table, align_right_from=2)
    path = out_dir / "leaf-size.md"
    path.write_text("\n".join(lines) + "\n")
    fig, (ax,) = new_figure(1)
    for i, (name, method) in enumerate(dict.fromkeys((r.scene, r.method) for r in rows)):
        mine = [r for r in rows if r.scene == name and r.method == method]
        ax.plot([r.leaf_size for r in mine], [r.trace_seconds for r in mine], "o-", color=f"C{i}",
                label=f"{name}, {method}")
    ax.axvspan(2, 8, color="grey", alpha=0.15, label="lecture: often 2 to 8")
    ax.set(xscale="log", xlabel="leaf size", ylabel="seconds for the primary rays", title="leaf size sweep")
    swept = sorted({r.leaf_size for r in rows})
    ax.set_xticks(swept, [str(s) for s in swept])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return path, save_figure(fig, out_dir / "leaf-size.png")
