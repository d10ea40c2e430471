"""Refitting a BVH to moved primitives: the same tree, its boxes recomputed bottom-up.

For animated or deformed meshes whose faces stay the same (Wald, Boulos &
Shirley, "Ray Tracing Deformable Scenes Using Dynamic Bounding Volume
Hierarchies", ACM TOG 2007; Embree's ``rtcCommitScene`` on
``RTC_BUILD_QUALITY_REFIT`` geometry): every leaf box becomes the box of its
primitives' new positions and every inner box the union of its children's,
level by level from the deepest, all nodes of a level in parallel. The tree's
topology and leaf order are kept, so refitting costs a fraction of a build,
but the boxes may overlap more than a fresh build's would: the SAH cost before
and after (``stats()["sah_cost_at_build"]`` and ``["sah_cost"]``) tells when a
rebuild pays.
"""

from __future__ import annotations

import time

import numpy as np
from numba import prange

from ..._jit import parallel_kernel
from ...geometry.bounds import primitive_bounds
from ...scene import Spheres, TriangleMesh
from .nodes import node_depths

__all__ = ["depth_levels", "refit_boxes", "refitted_scene", "refit_bvh"]


def depth_levels(node_first: np.ndarray, node_count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(by_depth, level_first)``: the nodes sorted by depth, and where each depth starts in
    that order (``level_first[d] .. level_first[d + 1]``)."""
    depth = node_depths(node_first, node_count)
    by_depth = np.argsort(depth, kind="stable")
    level_first = np.zeros(int(depth.max()) + 2, dtype=np.int64)
    np.cumsum(np.bincount(depth), out=level_first[1:])
    return by_depth, level_first


@parallel_kernel
def refit_boxes(node_first, node_count, leaf_lo, leaf_hi, by_depth, level_first, node_box):
    """Write into ``node_box`` (n_nodes, 6) the box of every node: for a leaf, of the primitive
    boxes ``leaf_lo``/``leaf_hi`` (in leaf order) of its primitives; for an inner node, the
    union of its two children's. Levels go deepest first, each level's nodes in parallel."""
    for level in range(level_first.shape[0] - 2, -1, -1):
        for j in prange(level_first[level], level_first[level + 1]):
            node = by_depth[j]
            first = node_first[node]
            count = node_count[node]
            for k in range(3):
                node_box[node, k] = np.inf
                node_box[node, k + 3] = -np.inf
            if count > 0:
                for p in range(first, first + count):
                    for k in range(3):
                        node_box[node, k] = min(node_box[node, k], leaf_lo[p, k])
                        node_box[node, k + 3] = max(node_box[node, k + 3], leaf_hi[p, k])
            else:
                for child in range(first, first + 2):
                    for k in range(3):
                        node_box[node, k] = min(node_box[node, k], node_box[child, k])
                        node_box[node, k + 3] = max(node_box[node, k + 3], node_box[child, k + 3])


def refitted_scene(scene, vertices):
    """``scene`` with its primitives moved: a mesh with the same faces over ``vertices``
    (V, 3), or spheres with the same radii at the centres ``vertices`` (N, 3)."""
    if isinstance(scene, TriangleMesh):
        expected, name = scene.vertices.shape, "vertices"
    elif isinstance(scene, Spheres):
        expected, name = scene.centers.shape, "centers"
    else:
        raise TypeError(f"cannot refit a {type(scene).__name__}")
    shape = np.shape(vertices)
    if shape != expected:
        raise ValueError(f"refit needs {name} of the built scene's shape {expected}, got {shape}")
    if isinstance(scene, TriangleMesh):
        return TriangleMesh(vertices, scene.faces)
    return Spheres(vertices, scene.radii)


def refit_bvh(accel, vertices, padding) -> None:
    """Move ``accel`` (a built BVH) to the new positions ``vertices`` of its scene's primitives
    and refit its boxes; ``padding(node_box)`` is the rounding margin its build adds."""
    start = time.perf_counter()
    if not hasattr(accel, "sah_cost_at_build"):
        accel.sah_cost_at_build = accel._structure_stats()["sah_cost"]
    scene = refitted_scene(accel.scene, vertices)
    b = accel.bvh
    geometry = np.ascontiguousarray(scene.geometry[b.prim_order])
    leaf_lo, leaf_hi, scene_lo, scene_hi = primitive_bounds(scene.kind, geometry)
    if getattr(accel, "_depth_levels", None) is None:
        accel._depth_levels = depth_levels(b.node_first, b.node_count)
    box = np.empty_like(b.node_box)
    refit_boxes(b.node_first, b.node_count, leaf_lo, leaf_hi, *accel._depth_levels, box)
    pad = padding(box)
    box[:, :3] -= pad
    box[:, 3:] += pad
    accel.scene = scene
    accel.geometry = geometry
    accel.scene_box = scene_lo, scene_hi
    accel._pack_for_traversal(box, b.node_first, b.node_count, b.prim_order, pad)
    accel.refits = getattr(accel, "refits", 0) + 1
    accel.refit_seconds = time.perf_counter() - start
