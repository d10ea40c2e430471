"""The lecture's kd-tree statistics table, for the kd-tree or any other structure.

One column per scene, with the lecture's figure beside ours where it has one
(kept in ``rayaccel/data/lecture.json``; only ranges over its scenes survive,
so a range is printed). The rows:

* the tree: triangles, leaves, non-empty leaves, construction time, triangles
  per non-empty leaf, and why leaves ended (at the leaf size, at the depth
  limit, or because the SAH found no split worth its cost);
* **whole-tree SAH sums** (Wald & Havran 2006, section 3; MacDonald & Booth
  1990; Mitsuba's kd-tree statistics compute the same): for a ray that meets
  the root cell, the expected interior nodes ``sum_inner S/S_root``, leaves
  ``sum_leaves S/S_root`` and intersections ``sum_leaves N S/S_root`` it
  visits if it walks *every* cell it crosses, and their cost
  ``C_T steps + C_I intersections`` with the build's constants. This is the
  cost model the builder minimises, and it ignores that a ray stops at its
  first hit;
* **first-hit expectation over random lines**: the same three counts averaged
  over 100,000 seeded isotropic random lines through the scene's box
  (:func:`rayaccel.rays.random_lines`, the measure the surface area heuristic
  assumes), each traced from outside the box to its first hit, and the cost
  ``15 steps + 20 intersections`` as the lecture's ``exp cost`` row computes
  it. The lecture's steps and leaves match this definition on our trees;
* measured on camera rays that reach the object: the camera fills the image
  with the object (:meth:`rayaccel.Camera.filling`), the fraction of its rays
  that hit is printed, and the interior nodes, leaves and intersections per
  ray, closest hit; the render time of one frame (primary rays plus one shadow
  ray per hit).

For the kd-tree the table builds the lecture's trees, whose text says splits go
on until a fixed number of triangles is reached: leaves of at most 2 triangles,
and intersections costed 20 traversal steps, so that the cost termination
hardly ever stops a split before the leaf size or the depth limit do (2.31-2.44
triangles per non-empty leaf on the armadillo, Buddha, bunny and 203k dragon, 2.13
on the full dragon, against the lecture's 2.31-2.56; 3.5 with the default options). ``--method`` tabulates any other
structure with its default options (a row it has no figure for shows "-"); a grid's
cells are all leaves.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..catalog import load_scene
from ..rays import Camera, random_lines
from ..render import render, warm_up
from ..structures.registry import build
from ._report import build_and_render_bars, markdown_table

__all__ = ["DEFAULT_SCENES", "LECTURE_OPTIONS", "ROWS", "LINES", "lecture_figures", "run", "measure", "write_report"]

DEFAULT_SCENES = ("dragon", "dragon-203k", "armadillo", "buddha", "bunny", "forest", "forest-large-chair",
                  "forest-small-chair")

LECTURE_OPTIONS = {"kdtree": {"leaf_size": 2, "intersection_cost": 20.0, "skip_empty": False, "width": 2}}
"""Options of the lecture's trees, per method; other methods are built with their defaults. The
kd-tree is walked as a binary tree that enters empty leaves, as the lecture's is, so that its steps
and leaves are counted as the lecture counts them."""

LINES = 100_000
"""Random lines of the first-hit expectation."""

STEP_COST, TEST_COST = 15.0, 20.0
"""The lecture's costs of a traversal step and an intersection in its ``exp cost`` row."""

# (row label, statistic key, format)
ROWS = (
    ("# triangles", "primitives", "{:,}"),
    ("# leaf nodes", "leaves", "{:,}"),
    ("# non-empty leaf nodes", "nonempty_leaves", "{:,}"),
    ("construction time", "build_seconds", "{:.3f} s"),
    ("avg # triangles / non-empty leaf node", "avg_prims_per_nonempty_leaf", "{:.2f}"),
    ("leaves ended at the leaf size", "leaves_at_leaf_size", "{:,}"),
    ("leaves ended at the depth limit", "leaves_at_depth_limit", "{:,}"),
    ("leaves ended by the SAH cost", "leaves_by_cost", "{:,}"),
    ("whole tree: exp # traversal steps", "expected_traversal_steps", "{:.1f}"),
    ("whole tree: exp # leaves visited", "expected_leaves_visited", "{:.2f}"),
    ("whole tree: exp # intersections", "expected_intersections", "{:.2f}"),
    ("whole tree: exp cost (C_T, C_I of the build)", "expected_cost", "{:.1f}"),
    ("first hit: exp # traversal steps", "first_hit_traversal_steps", "{:.1f}"),
    ("first hit: exp # leaves visited", "first_hit_leaves_visited", "{:.2f}"),
    ("first hit: exp # intersections", "first_hit_intersections", "{:.2f}"),
    ("first hit: exp cost (15 steps + 20 intersections)", "first_hit_cost", "{:.1f}"),
    ("render time", "render_seconds", "{:.3f} s"),
    ("camera rays that hit the object", "hit_fraction", "{:.0%}"),
    ("avg # nodes / ray", "avg_nodes_per_ray", "{:.1f}"),
    ("avg # leaves / ray", "avg_leaves_per_ray", "{:.2f}"),
    ("avg # intersections / ray", "avg_intersections_per_ray", "{:.2f}"),
)


def lecture_figures() -> dict:
    """The lecture's figures of the table, by statistic key, and their source."""
    data = json.loads((Path(__file__).resolve().parent.parent / "data" / "lecture.json").read_text())
    return {"source": data["source"], **data["kdtree_table"]}


def _object_points(scene) -> np.ndarray:
    bounds = scene.bounds()
    return np.vstack((bounds.lo, bounds.hi))


def first_hit_expectation(accel, n_lines: int = LINES, seed: int = 0) -> dict:
    """Interior nodes, leaves and intersections per random line through the scene's box,
    each traced to its first hit, and their cost as the lecture's ``exp cost`` row."""
    origins, directions = random_lines(*accel.scene_box, n_lines, seed=seed)
    counters = accel.intersect(origins, directions, counters=True).counters
    leaves = float(counters.leaves.mean())
    steps = float(counters.nodes.mean()) - leaves
    tests = float(counters.tests.mean())
    return {"first_hit_traversal_steps": steps, "first_hit_leaves_visited": leaves,
            "first_hit_intersections": tests, "first_hit_cost": STEP_COST * steps + TEST_COST * tests}


def measure(name: str, scene, method: str, side: int) -> tuple[dict, object]:
    """Statistics of ``method`` (with the lecture's options where it has some) on one scene,
    with the render time of a ``side`` x ``side`` frame; returns them and the rendered frame."""
    start = time.perf_counter()
    accel = build(scene, method, **LECTURE_OPTIONS.get(method, {}))
    build_seconds = time.perf_counter() - start
    camera = Camera.filling(_object_points(scene))
    origins, directions = camera.rays(side, side)
    stats = accel.stats(origins, directions)
    stats.update(first_hit_expectation(accel))
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
    lecture = lecture_figures()
    headers = ["", "lecture"] + [c["scene"] for c in columns]
    table = [[label, lecture.get(key, "")] + [fmt.format(c[key]) if key in c else "-" for c in columns]
             for label, key, fmt in ROWS]
    options = LECTURE_OPTIONS.get(method, {})
    built = ", ".join(f"{k}={v}" for k, v in options.items()) or "default options"
    lines = [f"# The kd-tree table for `{method}` ({built})", "",
             "Whole tree: the SAH sums over every cell a ray meeting the root crosses (what the builder minimises). "
             f"First hit: averaged over {LINES:,} seeded random lines through the scene's box, each traced to its "
             "first hit. Measured rows: camera rays of a camera the object fills; render time of one "
             f"{side}x{side} frame, primary rays plus one shadow ray per hit and light. A grid's cells are all leaves.",
             "", f"Lecture: {lecture['source']} Our armadillo is the decimated 100k-triangle one; the lecture's "
             "neptune, forest and chair are not available, and the procedural forest scenes stand in.", ""]
    lines += markdown_table(headers, table, align_right_from=2)
    path = out_dir / f"kdtree-table-{method}.md"
    path.write_text("\n".join(lines) + "\n")
    return path, build_and_render_bars([c["scene"] for c in columns], [c["build_seconds"] for c in columns],
                                       [c["render_seconds"] for c in columns], method, side,
                                       out_dir / f"kdtree-table-{method}.png")
