"""Adaptive octree construction, level by level.

Glassner, "Space Subdivision for Fast Ray Tracing", IEEE CG&A 1984: a cell
holding more than ``leaf_size`` primitives is split at its centre into eight
octants, each receiving the primitives that overlap it, until cells are small
enough or ``max_depth`` is reached. A split that leaves every primitive in
each of several occupied octants (they all straddle the centre) gains nothing
and is not made, nor one that would more than quadruple the references (large
primitives crowding a corner); one that leaves them all in a single octant
still cuts off empty space and is made.

Each level is built in two parallel passes over the cells being split (count
the references per octant, then write them after a prefix sum), so the build
is breadth first and the eight children of a node are allocated side by side.
Primitives go into the octants their bounding box overlaps, or with ``exact``
only those they really overlap (triangle-box SAT, sphere-box distance). Octant
boxes are grown by ``pad`` so that a primitive touching a plane is found on
both sides of it.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..._jit import kernel, parallel_kernel
from ...geometry.overlap import prim_overlaps_box
from ..build_arrays import reserve_rows

__all__ = ["build_octree"]


@kernel
def _octant_span(lo, hi, center, pad):
    """For one axis: whether a box ``lo..hi`` reaches the lower and the upper half."""
    return lo <= center + pad, hi >= center - pad


@kernel
def _visit_octants(prim, prim_lo, prim_hi, kind, geom, exact, center, half, pad, counts, row, out, cursor):
    """Count (``out`` empty) or write the octants of ``prim`` for the node in row ``row``."""
    below_x, above_x = _octant_span(prim_lo[prim, 0], prim_hi[prim, 0], center[0], pad[0])
    below_y, above_y = _octant_span(prim_lo[prim, 1], prim_hi[prim, 1], center[1], pad[1])
    below_z, above_z = _octant_span(prim_lo[prim, 2], prim_hi[prim, 2], center[2], pad[2])
    # a box inside one octant certainly meets it: only a primitive spanning several needs the test
    test = exact and ((below_x and above_x) or (below_y and above_y) or (below_z and above_z))
    for octant in range(8):
        bx = octant & 1
        by = (octant >> 1) & 1
        bz = (octant >> 2) & 1
        if not ((above_x if bx else below_x) and (above_y if by else below_y) and (above_z if bz else below_z)):
            continue
        if test:
            cx = center[0] + (0.5 if bx else -0.5) * half[0]
            cy = center[1] + (0.5 if by else -0.5) * half[1]
            cz = center[2] + (0.5 if bz else -0.5) * half[2]
            if not prim_overlaps_box(kind, geom, prim, cx, cy, cz, 0.5 * half[0] + pad[0], 0.5 * half[1] + pad[1],
                                     0.5 * half[2] + pad[2]):
                continue
        if out.shape[0] == 0:
            counts[row, octant] += 1
        else:
            out[cursor[row, octant]] = prim
            cursor[row, octant] += 1


@parallel_kernel
def _split_level(refs, ref_first, centers, halves, split, prim_lo, prim_hi, kind, geom, exact, pad_fraction,
                 counts, out, cursor):
    for row in prange(split.shape[0]):
        if not split[row]:
            continue
        pad = halves[row] * pad_fraction
        for k in range(ref_first[row], ref_first[row + 1]):
            _visit_octants(refs[k], prim_lo, prim_hi, kind, geom, exact, centers[row], halves[row], pad, counts,
                           row, out, cursor)


@kernel
def build_octree(prim_lo, prim_hi, kind, geom, exact, lo, hi, leaf_size, max_depth, pad_fraction):
    """Build over all primitives in the root cell ``lo``..``hi``. Returns
    ``(node_center, node_link, leaf_prims, depth)``; see :mod:`.layout`."""
    n = prim_lo.shape[0]
    node_center = np.empty((64, 3))
    node_link = np.empty((64, 2), dtype=np.int32)
    leaf_prims = np.empty(n + 16, dtype=np.int32)
    n_refs = 0
    refs = np.arange(n).astype(np.int32)
    ref_first = np.array([0, n], dtype=np.int64)
    rows = np.zeros(1, dtype=np.int64)
    centers = np.empty((1, 3))
    halves = np.empty((1, 3))
    centers[0] = 0.5 * (lo + hi)
    halves[0] = 0.5 * (hi - lo)
    node_center[0] = centers[0]
    n_nodes = 1
    depth = 0
    while rows.shape[0] > 0:
        m = rows.shape[0]
        split = np.zeros(m, dtype=np.bool_)
        for r in range(m):
            split[r] = ref_first[r + 1] - ref_first[r] > leaf_size and depth < max_depth
        counts = np.zeros((m, 8), dtype=np.int64)
        _split_level(refs, ref_first, centers, halves, split, prim_lo, prim_hi, kind, geom, exact, pad_fraction,
                     counts, np.empty(0, dtype=np.int32), counts)
        n_split = 0
        for r in range(m):
            if split[r]:
                nonempty = 0
                separated = False
                for octant in range(8):
                    nonempty += counts[r, octant] > 0
                    separated |= 0 < counts[r, octant] < ref_first[r + 1] - ref_first[r]
                count = ref_first[r + 1] - ref_first[r]
                split[r] = (separated and counts[r].sum() <= 4 * count) or nonempty == 1
            n_split += split[r]
        child_base = n_nodes
        node_center = reserve_rows(node_center, n_nodes + 8 * n_split)
        node_link = reserve_rows(node_link, n_nodes + 8 * n_split)
        next_first = np.zeros(8 * n_split + 1, dtype=np.int64)
        cursor = np.zeros((m, 8), dtype=np.int64)
        next_rows = np.empty(8 * n_split, dtype=np.int64)
        next_centers = np.empty((8 * n_split, 3))
        next_halves = np.empty((8 * n_split, 3))
        k = 0
        for r in range(m):
            node = rows[r]
            count = ref_first[r + 1] - ref_first[r]
            if not split[r]:
                leaf_prims = reserve_rows(leaf_prims, n_refs + count)
                leaf_prims[n_refs:n_refs + count] = refs[ref_first[r]:ref_first[r + 1]]
                node_link[node, 0] = n_refs
                node_link[node, 1] = count
                n_refs += count
                continue
            node_link[node, 0] = child_base + k
            node_link[node, 1] = -1
            for octant in range(8):
                child = child_base + k
                next_rows[k] = child
                for axis in range(3):
                    bit = (octant >> axis) & 1
                    next_halves[k, axis] = 0.5 * halves[r, axis]
                    next_centers[k, axis] = centers[r, axis] + (0.5 if bit else -0.5) * halves[r, axis]
                node_center[child] = next_centers[k]
                cursor[r, octant] = next_first[k]
                next_first[k + 1] = next_first[k] + counts[r, octant]
                k += 1
        n_nodes = child_base + k
        next_refs = np.empty(next_first[k], dtype=np.int32)
        _split_level(refs, ref_first, centers, halves, split, prim_lo, prim_hi, kind, geom, exact, pad_fraction,
                     counts, next_refs, cursor)
        refs = next_refs
        ref_first = next_first
        rows = next_rows
        centers = next_centers
        halves = next_halves
        depth += 1
    return node_center[:n_nodes].copy(), node_link[:n_nodes].copy(), leaf_prims[:n_refs].copy(), depth - 1
