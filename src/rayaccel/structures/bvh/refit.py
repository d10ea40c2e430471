"""Refitting a BVH to moved primitives: the same tree, its boxes recomputed bottom-up.

For animated or deformed meshes whose faces stay the same (Wald, Boulos &
Shirley, "Ray Tracing Deformable Scenes Using Dynamic Bounding Volume
Hierarchies", ACM TOG 2007; Embree's ``rtcCommitScene`` on
``RTC_BUILD_QUALITY_REFIT`` geometry): every leaf box becomes the box of its
primitives' new positions and every inner box the union of its children's,
the leaves in parallel, then the inner nodes in one pass from the last node back. The tree's
topology and leaf order are kept, so refitting costs a fraction of a build,
but the boxes may overlap more than a fresh build's would: the SAH cost before
and after (``stats()["sah_cost_at_build"]`` and ``["sah_cost"]``) tells when a
rebuild pays.
"""

from __future__ import annotations

import time

import numpy as np
from numba import prange

from ..._jit import kernel, parallel_kernel
from ...geometry.bounds import primitive_extent
from ...scene import Spheres, TriangleMesh
from .nodes import grow_by_rounding_margin

__all__ = ["refit_boxes", "refit_geometry_boxes", "refitted_scene", "refit_bvh"]


@kernel
def _inner_boxes(node_first, node_count, node_box):
    """Every inner node's box as the union of its children's, from the last node back
    (children follow their parents, so they are final when their parent is reached)."""
    for node in range(node_first.shape[0] - 1, -1, -1):
        if node_count[node] > 0:
            continue
        left = node_first[node]
        for k in range(3):
            node_box[node, k] = min(node_box[left, k], node_box[left + 1, k])
            node_box[node, k + 3] = max(node_box[left, k + 3], node_box[left + 1, k + 3])


@parallel_kernel
def refit_boxes(node_first, node_count, leaf_lo, leaf_hi, node_box):
    """Write into ``node_box`` (n_nodes, 6) the box of every node: for a leaf, of the boxes
    ``leaf_lo``/``leaf_hi`` (in leaf order) of its primitives, all leaves in parallel; then
    for the inner nodes the union of their children's, in one serial pass from the last
    node back (six comparisons a node; a parallel launch per level cost more)."""
    for node in prange(node_first.shape[0]):
        count = node_count[node]
        if count == 0:
            continue
        first = node_first[node]
        for k in range(3):
            node_box[node, k] = leaf_lo[first, k]
            node_box[node, k + 3] = leaf_hi[first, k]
        for p in range(first + 1, first + count):
            for k in range(3):
                node_box[node, k] = min(node_box[node, k], leaf_lo[p, k])
                node_box[node, k + 3] = max(node_box[node, k + 3], leaf_hi[p, k])
    _inner_boxes(node_first, node_count, node_box)


@parallel_kernel
def refit_geometry_boxes(kind, geometry, node_first, node_count, node_box):
    """:func:`refit_boxes` with the leaves' boxes taken straight from their primitives'
    ``geometry`` (in leaf order), without a box per primitive in between."""
    for node in prange(node_first.shape[0]):
        count = node_count[node]
        if count == 0:
            continue
        first = node_first[node]
        for k in range(3):
            node_box[node, k] = np.inf
            node_box[node, k + 3] = -np.inf
        for p in range(first, first + count):
            for k in range(3):
                lo, hi = primitive_extent(kind, geometry, p, k)
                node_box[node, k] = min(node_box[node, k], lo)
                node_box[node, k + 3] = max(node_box[node, k + 3], hi)
    _inner_boxes(node_first, node_count, node_box)


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


def refit_bvh(accel, vertices) -> None:
    """Move ``accel`` (a built BVH) to the new positions ``vertices`` of its scene's primitives
    and refit its boxes, grown by the rounding margin as its build grew them."""
    start = time.perf_counter()
    if not hasattr(accel, "sah_cost_at_build"):
        accel.sah_cost_at_build = accel.sah_cost()
    scene = refitted_scene(accel.scene, vertices)
    b = accel.bvh
    geometry = scene.gather(b.prim_order, out=accel.geometry)  # in place: the old positions are not needed
    box = b.node_box
    refit_geometry_boxes(scene.kind, geometry, b.node_first, b.node_count, box)
    scene_lo, scene_hi = box[0, :3].copy(), box[0, 3:].copy()
    pad = grow_by_rounding_margin(box)
    accel.scene = scene
    accel.geometry = geometry
    accel.scene_box = scene_lo, scene_hi
    accel._pack_for_traversal(box, b.node_first, b.node_count, b.prim_order, pad, same_tree=True, keep_binary=True)
    accel.refits = getattr(accel, "refits", 0) + 1
    accel.refit_seconds = time.perf_counter() - start
