"""Adaptive octree construction, level by level.

Glassner, "Space Subdivision for Fast Ray Tracing", IEEE CG&A 1984: a cell
holding more than ``leaf_size`` primitives is split at its centre into eight
octants, each receiving the primitives that overlap it, until cells are small
enough or ``max_depth`` is reached. A split that leaves every primitive in
each of several occupied octants (they all straddle the centre) gains nothing
and is not made, nor one that would more than quadruple the references (large
primitives crowding a corner); one that leaves them all in a single octant
still cuts off empty space and is made.

Each level is built in two parallel passes over the cells being split: the
first finds each reference's octants (kept as an 8-bit mask, so the overlap
tests run once) and counts the references per octant, the second writes them
after a prefix sum. The build is breadth first and the eight children of a
node are allocated side by side. Only cells over the leaf size get octant
counts, as the deep levels hold millions of cells that stay leaves.
Primitives go into the octants their bounding box overlaps, or with ``exact``
only those they really overlap (triangle-box SAT, sphere-box distance). Octant
boxes are grown by a pad so that a primitive touching a plane is found on
both sides of it: a fraction of the cell's size, plus a fraction of the
coordinates' magnitude, since a cell's centre far from the origin carries a
rounding error of that size (a mesh moved 1e7 along x, cells 0.03 wide: the
size term alone, 3e-11, lost a triangle whose vertex a ray started on).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ..._jit import inline_kernel, kernel, parallel_kernel
from ...geometry.overlap import prim_overlaps_box
from ..build_arrays import reserve_rows

__all__ = ["build_octree"]


@inline_kernel
def _octant_span(lo, hi, center, pad):
    """For one axis: whether a box ``lo..hi`` reaches the lower and the upper half."""
    return lo <= center + pad, hi >= center - pad


@inline_kernel
def _octant_mask(prim, prim_lo, prim_hi, kind, geom, exact, cx, cy, cz, hx, hy, hz, px, py, pz):
    """Bit ``o`` set for each octant ``o`` (x, y, z upper half at bits 0, 1, 2) of the cell with
    centre ``c``, half size ``h`` and insertion pad ``p`` that primitive ``prim`` goes into."""
    below_x, above_x = _octant_span(prim_lo[prim, 0], prim_hi[prim, 0], cx, px)
    below_y, above_y = _octant_span(prim_lo[prim, 1], prim_hi[prim, 1], cy, py)
    below_z, above_z = _octant_span(prim_lo[prim, 2], prim_hi[prim, 2], cz, pz)
    # a box inside one octant certainly meets it: only a primitive spanning several needs the test
    test = exact and ((below_x and above_x) or (below_y and above_y) or (below_z and above_z))
    mask = 0
    for octant in range(8):
        bx = octant & 1
        by = (octant >> 1) & 1
        bz = (octant >> 2) & 1
        if not ((above_x if bx else below_x) and (above_y if by else below_y) and (above_z if bz else below_z)):
            continue
        if test:
            ox = cx + (0.5 if bx else -0.5) * hx
            oy = cy + (0.5 if by else -0.5) * hy
            oz = cz + (0.5 if bz else -0.5) * hz
            if not prim_overlaps_box(kind, geom, prim, ox, oy, oz, 0.5 * hx + px, 0.5 * hy + py, 0.5 * hz + pz):
                continue
        mask |= 1 << octant
    return mask


@parallel_kernel
def _count_octants(refs, ref_first, centers, halves, slot, prim_lo, prim_hi, kind, geom, exact, pad_fraction,
                   coordinate_pad, counts, masks):
    """For every row with ``slot[row] >= 0``: each reference's octant mask into ``masks`` and the
    references per octant into ``counts[slot[row]]``."""
    for row in prange(slot.shape[0]):
        c = slot[row]
        if c < 0:
            continue
        cx, cy, cz = centers[row, 0], centers[row, 1], centers[row, 2]
        hx, hy, hz = halves[row, 0], halves[row, 1], halves[row, 2]
        px = hx * pad_fraction + coordinate_pad
        py = hy * pad_fraction + coordinate_pad
        pz = hz * pad_fraction + coordinate_pad
        for k in range(ref_first[row], ref_first[row + 1]):
            mask = _octant_mask(refs[k], prim_lo, prim_hi, kind, geom, exact, cx, cy, cz, hx, hy, hz, px, py, pz)
            masks[k] = mask
            for octant in range(8):
                counts[c, octant] += (mask >> octant) & 1


@parallel_kernel
def _write_octants(refs, ref_first, slot, masks, cursor, out):
    """For every row with ``slot[row] >= 0``: each reference into the octants of its mask, at the
    cursors ``cursor[slot[row]]``."""
    for row in prange(slot.shape[0]):
        c = slot[row]
        if c < 0:
            continue
        for k in range(ref_first[row], ref_first[row + 1]):
            for octant in range(8):
                if (masks[k] >> octant) & 1:
                    out[cursor[c, octant]] = refs[k]
                    cursor[c, octant] += 1


@kernel
def build_octree(prim_lo, prim_hi, kind, geom, exact, lo, hi, leaf_size, max_depth, pad_fraction, coordinate_pad):
    """Build over all primitives in the root cell ``lo``..``hi``, octant boxes grown by
    ``pad_fraction`` of their half size plus ``coordinate_pad``. Returns
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
        slot = np.full(m, -1, dtype=np.int64)
        n_candidates = 0
        for r in range(m):
            if ref_first[r + 1] - ref_first[r] > leaf_size and depth < max_depth:
                slot[r] = n_candidates
                n_candidates += 1
        counts = np.zeros((n_candidates, 8), dtype=np.int64)
        masks = np.empty(refs.shape[0], dtype=np.uint8)
        _count_octants(refs, ref_first, centers, halves, slot, prim_lo, prim_hi, kind, geom, exact, pad_fraction,
                       coordinate_pad, counts, masks)
        n_split = 0
        leaf_refs = 0
        for r in range(m):
            count = ref_first[r + 1] - ref_first[r]
            c = slot[r]
            if c >= 0:
                nonempty = 0
                separated = False
                total = 0
                for octant in range(8):
                    nonempty += counts[c, octant] > 0
                    separated |= 0 < counts[c, octant] < count
                    total += counts[c, octant]
                if not ((separated and total <= 4 * count) or nonempty == 1):
                    slot[r] = -1
            if slot[r] >= 0:
                n_split += 1
            else:
                leaf_refs += count
        child_base = n_nodes
        node_center = reserve_rows(node_center, n_nodes + 8 * n_split)
        node_link = reserve_rows(node_link, n_nodes + 8 * n_split)
        leaf_prims = reserve_rows(leaf_prims, n_refs + leaf_refs)
        next_first = np.zeros(8 * n_split + 1, dtype=np.int64)
        cursor = np.zeros((n_candidates, 8), dtype=np.int64)
        next_rows = np.empty(8 * n_split, dtype=np.int64)
        next_centers = np.empty((8 * n_split, 3))
        next_halves = np.empty((8 * n_split, 3))
        k = 0
        for r in range(m):
            node = rows[r]
            c = slot[r]
            if c < 0:
                node_link[node, 0] = n_refs
                node_link[node, 1] = ref_first[r + 1] - ref_first[r]
                for j in range(ref_first[r], ref_first[r + 1]):
                    leaf_prims[n_refs] = refs[j]
                    n_refs += 1
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
                    node_center[child, axis] = next_centers[k, axis]
                cursor[c, octant] = next_first[k]
                next_first[k + 1] = next_first[k] + counts[c, octant]
                k += 1
        n_nodes = child_base + k
        next_refs = np.empty(next_first[k], dtype=np.int32)
        _write_octants(refs, ref_first, slot, masks, cursor, next_refs)
        refs = next_refs
        ref_first = next_first
        rows = next_rows
        centers = next_centers
        halves = next_halves
        depth += 1
    return node_center[:n_nodes].copy(), node_link[:n_nodes].copy(), leaf_prims[:n_refs].copy(), depth - 1
