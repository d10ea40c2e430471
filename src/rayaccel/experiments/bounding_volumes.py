"""The lecture's "cheap vs tight" bounding volumes, measured.

For each volume type (axis-aligned box, sphere fitted over the primitives,
sphere fitted over the child spheres, 14-DOP), on real meshes, with the same
binned-SAH tree:

* cost of one ray-volume test, in nanoseconds: incoherent rays against every
  node volume of the tree (all threads);
* tightness: the mean over inner nodes of SA(child) / SA(parent), the
  probability that a ray hitting the parent also hits the child (for convex
  bodies the mean projected area is a quarter of the surface area, so the
  ratio of areas is the ratio of hit probabilities);
* what a hierarchy built with it costs: expected nodes visited from the
  areas, measured nodes and tests per primary ray, and the closest-hit time of
  the primary rays.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import prange

from .._jit import parallel_kernel
from .._timing import median_seconds
from ..catalog import load_scene
from ..geometry.kdop import KDOP_NORMALS
from ..render import default_camera
from ..structures.bvh.traverse import KDOP, _enter, volume_ray_setup
from ..structures.registry import build
from ._report import markdown_table, new_figure, save_figure
from .bvh_builders import incoherent_rays

__all__ = ["VOLUMES", "VolumeRow", "run", "write_report"]

VOLUMES = {
    "aabb": {"bounds": "aabb", "width": 2},  # the binary walk over the same tree as the other volumes
    "sphere (Ritter over primitives)": {"bounds": "sphere", "sphere_fit": "primitives"},
    "sphere (over child spheres)": {"bounds": "sphere", "sphere_fit": "children"},
    "14-DOP": {"bounds": "kdop"},
}


@parallel_kernel
def _test_all_volumes(bounds_kind, box, volume, origins, directions, n_nodes):
    hits = np.zeros(origins.shape[0], dtype=np.int64)
    for i in prange(origins.shape[0]):
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        ray = (ox, oy, oz, dx, dy, dz)
        proj_o, proj_inv, near = volume_ray_setup(ox, oy, oz, dx, dy, dz, KDOP_NORMALS, bounds_kind == KDOP)
        count = 0
        for node in range(n_nodes):
            if _enter(bounds_kind, box, volume, node, ray, proj_o, proj_inv, near, 0.0, np.inf) != np.inf:
                count += 1
        hits[i] = count
    return hits


@dataclass
class VolumeRow:
    scene: str
    volume: str
    test_ns: float
    tightness: float
    expected_nodes: float
    nodes_per_ray: float
    tests_per_ray: float
    trace_seconds: float
    build_seconds: float


def _tightness(accel) -> float:
    areas = accel.volume_areas()
    b = accel.bvh
    inner = np.flatnonzero(b.node_count == 0)
    children = np.concatenate([b.node_first[inner], b.node_first[inner] + 1])
    parents = np.concatenate([inner, inner])
    return float(np.mean(areas[children] / areas[parents]))


def run(scenes=("bunny", "dragon-203k", "armadillo"), side: int = 512, progress=None) -> list[VolumeRow]:
    rows = []
    total = len(scenes) * len(VOLUMES)
    for s, name in enumerate(scenes):
        scene = load_scene(name)
        primary = default_camera(scene).rays(side, side)
        probe = incoherent_rays(scene, 2000, seed=1)
        for v, (label, options) in enumerate(VOLUMES.items()):
            accel = build(scene, "bvh-binned", **options)
            n_nodes = min(accel.bvh.n_nodes, 4096)
            seconds = median_seconds(lambda: _test_all_volumes(accel.bounds_kind, accel.bvh.node_box, accel.volume,
                                                               probe[0], probe[1], n_nodes), repeats=3)
            stats = accel.stats(*primary)
            trace = median_seconds(lambda: accel.intersect(*primary), repeats=3)
            rows.append(VolumeRow(name, label, seconds / (len(probe[0]) * n_nodes) * 1e9, _tightness(accel),
                                  stats["expected_traversal_steps"] + stats["expected_leaves_visited"],
                                  stats["avg_nodes_per_ray"], stats["avg_intersections_per_ray"], trace,
                                  accel.build_seconds))
            if progress is not None:
                progress(s * len(VOLUMES) + v + 1, total)
    return rows


def write_report(rows: list[VolumeRow], out_dir, side: int) -> tuple[Path, Path]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    headers = ["scene", "volume", "ns per ray test (2 threads)", "tightness P(child | parent)",
               "expected nodes/ray", "nodes/ray", "tests/ray", f"trace s ({side}x{side})", "build s"]
    table = [[r.scene, r.volume, f"{r.test_ns:.2f}", f"{r.tightness:.3f}", f"{r.expected_nodes:.1f}",
              f"{r.nodes_per_ray:.1f}", f"{r.tests_per_ray:.2f}", f"{r.trace_seconds:.3f}", f"{r.build_seconds:.2f}"]
             for r in rows]
    lines = ["# Cheap vs tight bounding volumes (binned-SAH BVH, closest hit on primary rays)", "",
             "Tightness: mean over inner nodes of SA(child)/SA(parent), the probability that a ray hitting the "
             "parent also hits the child. Expected nodes: sum of node areas over the root's area.", ""]
    lines += markdown_table(headers, table, align_right_from=2)
    path = out_dir / "bounding-volumes.md"
    path.write_text("\n".join(lines) + "\n")
    fig, (left,) = new_figure(1)
    for i, label in enumerate(VOLUMES):
        mine = [r for r in rows if r.volume == label]
        left.scatter([r.test_ns for r in mine], [r.tightness for r in mine],
                     s=[20 + 400 * r.trace_seconds for r in mine], color=f"C{i}", label=label, alpha=0.7)
    left.set(xlabel="ns per ray-volume test", ylabel="tightness P(child | parent)",
             title="cheap vs tight (marker area: trace time)")
    left.grid(True, alpha=0.3)
    left.legend(fontsize=8)
    return path, save_figure(fig, out_dir / "bounding-volumes.png")
