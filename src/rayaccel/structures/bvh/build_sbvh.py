"""Top-down BVH over triangles with spatial splits (SBVH).

Stich, Friedrich & Dietrich, "Spatial Splits in Bounding Volume Hierarchies",
High-Performance Graphics 2009. A node chooses between the binned SAH object
split (Wald 2007, as :mod:`.split_sah_binned`) and a spatial split: a plane
that cuts the triangles straddling it into two references, each bounded by the
box of the triangle's part on its side. Spatial splits are tried only where the
object split's two children overlap by more than ``alpha`` of the root's area,
and only while the references made by cutting stay within ``split_budget`` of
the triangle count. A triangle can then lie in several leaves: its references
share the primitive index in ``order``, and each leaf's box bounds only the
part it holds.

The references live in one pool of rows (primitive, box). A task owns a range
of it: an object split partitions the range in place; a spatial split keeps the
left child in place (the triangles wholly left, then the left parts of the cut
ones) and writes the right child above the pool's top. The tasks run depth
first, the newest first, so the rows above the running task's range belong to
finished subtrees and are reused.
"""

from __future__ import annotations

import numpy as np

from ..._jit import kernel, unsigned
from .nodes import box_area6

__all__ = ["build_sbvh", "clipped_triangle_box"]


@kernel
def _grow_point(box, x, y, z):
    box[0] = min(box[0], x)
    box[1] = min(box[1], y)
    box[2] = min(box[2], z)
    box[3] = max(box[3], x)
    box[4] = max(box[4], y)
    box[5] = max(box[5], z)


@kernel
def clipped_triangle_box(vertices, face, axis, plane_lo, plane_hi, bound, out):
    """Write into ``out`` the box of the part of triangle ``face`` (its three vertex indices)
    between the planes ``plane_lo <= p[axis] <= plane_hi``, intersected with ``bound``; returns
    whether it is non-empty. The part's corners are the vertices inside the slab and the points
    where the edges cross its planes."""
    for k in range(3):
        out[k] = np.inf
        out[k + 3] = -np.inf
    for i in range(3):
        p = unsigned(face[i])
        q = unsigned(face[(i + 1) % 3])
        pa = vertices[p, axis]
        qa = vertices[q, axis]
        if plane_lo <= pa <= plane_hi:
            _grow_point(out, vertices[p, 0], vertices[p, 1], vertices[p, 2])
        for plane in (plane_lo, plane_hi):
            if (pa < plane < qa) or (qa < plane < pa):
                s = (plane - pa) / (qa - pa)
                x = plane if axis == 0 else vertices[p, 0] + s * (vertices[q, 0] - vertices[p, 0])
                y = plane if axis == 1 else vertices[p, 1] + s * (vertices[q, 1] - vertices[p, 1])
                z = plane if axis == 2 else vertices[p, 2] + s * (vertices[q, 2] - vertices[p, 2])
                _grow_point(out, x, y, z)
    empty = False
    for k in range(3):
        out[k] = max(out[k], bound[k])
        out[k + 3] = min(out[k + 3], bound[k + 3])
        if out[k] > out[k + 3]:
            empty = True
    return not empty


@kernel
def _swap_refs(ref_prim, ref_box, i, j):
    ref_prim[i], ref_prim[j] = ref_prim[j], ref_prim[i]
    for k in range(6):
        ref_box[i, k], ref_box[j, k] = ref_box[j, k], ref_box[i, k]


@kernel
def _bounds(ref_box, start, end, box, centroid_box):
    for k in range(3):
        box[k] = np.inf
        box[k + 3] = -np.inf
        centroid_box[k] = np.inf
        centroid_box[k + 3] = -np.inf
    for i in range(start, end):
        for k in range(3):
            box[k] = min(box[k], ref_box[i, k])
            box[k + 3] = max(box[k + 3], ref_box[i, k + 3])
            c = 0.5 * (ref_box[i, k] + ref_box[i, k + 3])
            centroid_box[k] = min(centroid_box[k], c)
            centroid_box[k + 3] = max(centroid_box[k + 3], c)


@kernel
def _union_into(acc, box, row):
    for k in range(3):
        acc[k] = min(acc[k], box[row, k])
        acc[k + 3] = max(acc[k + 3], box[row, k + 3])


@kernel
def _empty(box):
    for k in range(3):
        box[k] = np.inf
        box[k + 3] = -np.inf


@kernel
def _object_split(ref_box, start, end, centroid_box, bins, bin_box, bin_count, right_area, acc, child_box):
    """The binned SAH over the references' box centres: ``(axis, bin, sah)``, the cut after
    ``bin`` on ``axis`` and its ``A_L n_L + A_R n_R``, and the children's boxes in
    ``child_box``; ``axis`` is -1 when all centres coincide."""
    n = end - start
    scale = np.zeros(3)
    for axis in range(3):
        extent = centroid_box[axis + 3] - centroid_box[axis]
        if extent > 0.0:
            scale[axis] = bins / extent
    for b in range(3 * bins):
        bin_count[b] = 0
        _empty(bin_box[b])
    for i in range(start, end):
        for axis in range(3):
            c = 0.5 * (ref_box[i, axis] + ref_box[i, axis + 3])
            b = axis * bins + min(int((c - centroid_box[axis]) * scale[axis]), bins - 1)
            bin_count[b] += 1
            _union_into(bin_box[b], ref_box, i)
    best = np.inf
    best_axis = -1
    best_bin = -1
    for axis in range(3):
        if scale[axis] == 0.0:
            continue
        first = axis * bins
        _empty(acc)
        count = 0
        for b in range(bins - 1, 0, -1):
            count += bin_count[first + b]
            _union_into(acc, bin_box, first + b)
            right_area[b] = box_area6(acc) * count
        _empty(acc)
        count = 0
        for b in range(bins - 1):
            count += bin_count[first + b]
            _union_into(acc, bin_box, first + b)
            if count == 0 or count == n:
                continue
            cost = box_area6(acc) * count + right_area[b + 1]
            if cost < best:
                best, best_axis, best_bin = cost, axis, b
    if best_axis >= 0:
        _empty(child_box[0])
        _empty(child_box[1])
        for b in range(bins):
            _union_into(child_box[0 if b <= best_bin else 1], bin_box, best_axis * bins + b)
    return best_axis, best_bin, best, scale[max(best_axis, 0)]


@kernel
def _spatial_split(vertices, faces, ref_prim, ref_box, start, end, box, bins, bin_box, entries, exits, right_area,
                   acc, clipped):
    """The best spatial split of the node with box ``box``: ``bins`` equal slabs per axis, each
    reference's triangle clipped into every slab it spans; returns ``(axis, plane, sah)``."""
    best = np.inf
    best_axis = -1
    best_plane = 0.0
    for axis in range(3):
        lo = box[axis]
        extent = box[axis + 3] - lo
        if not extent > 0.0:
            continue
        width = extent / bins
        for b in range(bins):
            entries[b] = 0
            exits[b] = 0
            _empty(bin_box[b])
        for i in range(start, end):
            first = min(max(int((ref_box[i, axis] - lo) / width), 0), bins - 1)
            last = min(max(int((ref_box[i, axis + 3] - lo) / width), first), bins - 1)
            entries[first] += 1
            exits[last] += 1
            if first == last:
                _union_into(bin_box[first], ref_box, i)
                continue
            face = faces[ref_prim[i]]
            for b in range(first, last + 1):
                slab_lo = max(lo + b * width, ref_box[i, axis])
                slab_hi = min(lo + (b + 1) * width if b < bins - 1 else box[axis + 3], ref_box[i, axis + 3])
                if clipped_triangle_box(vertices, face, axis, slab_lo, slab_hi, ref_box[i], clipped):
                    for k in range(3):
                        bin_box[b, k] = min(bin_box[b, k], clipped[k])
                        bin_box[b, k + 3] = max(bin_box[b, k + 3], clipped[k + 3])
        _empty(acc)
        count = 0
        for b in range(bins - 1, 0, -1):
            count += exits[b]
            _union_into(acc, bin_box, b)
            right_area[b] = box_area6(acc) * count
        _empty(acc)
        count = 0
        for b in range(bins - 1):
            count += entries[b]
            _union_into(acc, bin_box, b)
            cost = box_area6(acc) * count + right_area[b + 1]
            if cost < best:
                best, best_axis, best_plane = cost, axis, lo + (b + 1) * width
    return best_axis, best_plane, best


@kernel
def _partition_objects(ref_prim, ref_box, start, end, axis, best_bin, c_lo, scale, bins):
    left = start
    right = end - 1
    while left <= right:
        c = 0.5 * (ref_box[left, axis] + ref_box[left, axis + 3])
        if min(int((c - c_lo) * scale), bins - 1) <= best_bin:
            left += 1
        else:
            _swap_refs(ref_prim, ref_box, left, right)
            right -= 1
    return left


@kernel
def _partition_space(vertices, faces, ref_prim, ref_box, start, end, axis, plane, top, clipped):
    """Split the references ``start:end`` at ``plane`` on ``axis``: the left child's become rows
    ``start:mid`` (wholly left, then the left parts of the cut ones), the right child's rows
    ``top:right_end`` (the right parts, then the wholly right). Returns ``(mid, right_end, cut)``."""
    left = start
    right = end - 1
    i = start
    while i <= right:
        if ref_box[i, axis + 3] <= plane:
            _swap_refs(ref_prim, ref_box, i, left)
            left += 1
            i += 1
        elif ref_box[i, axis] >= plane:
            _swap_refs(ref_prim, ref_box, i, right)
            right -= 1
        else:
            i += 1
    out = top
    mid = left
    for i in range(left, right + 1):
        face = faces[ref_prim[i]]
        if clipped_triangle_box(vertices, face, axis, plane, ref_box[i, axis + 3], ref_box[i], clipped):
            ref_prim[out] = ref_prim[i]
            for k in range(6):
                ref_box[out, k] = clipped[k]
            out += 1
        if clipped_triangle_box(vertices, face, axis, ref_box[i, axis], plane, ref_box[i], clipped):
            ref_prim[mid] = ref_prim[i]
            for k in range(6):
                ref_box[mid, k] = clipped[k]
            mid += 1
    for i in range(right + 1, end):
        ref_prim[out] = ref_prim[i]
        for k in range(6):
            ref_box[out, k] = ref_box[i, k]
        out += 1
    return mid, out, right + 1 - left


@kernel
def _build(vertices, faces, lo, hi, max_leaf_size, bins, traversal_cost, intersection_cost, max_cuts, alpha):
    n = lo.shape[0]
    capacity = 3 * (n + max_cuts) + 64
    ref_prim = np.empty(capacity, dtype=np.int64)
    ref_box = np.empty((capacity, 6))
    for i in range(n):
        ref_prim[i] = i
        for k in range(3):
            ref_box[i, k] = lo[i, k]
            ref_box[i, k + 3] = hi[i, k]
    node_capacity = 2 * (n + max_cuts) + 1
    node_box = np.empty((node_capacity, 6))
    node_first = np.empty(node_capacity, dtype=np.int32)
    node_count = np.empty(node_capacity, dtype=np.int32)
    order = np.empty(n + max_cuts, dtype=np.int64)
    task_node = np.empty(node_capacity, dtype=np.int64)
    task_start = np.empty(node_capacity, dtype=np.int64)
    task_end = np.empty(node_capacity, dtype=np.int64)
    box = np.empty(6)
    centroid_box = np.empty(6)
    bin_box = np.empty((3 * bins, 6))
    bin_count = np.empty(3 * bins, dtype=np.int64)
    exits = np.empty(bins, dtype=np.int64)
    right_area = np.empty(bins)
    acc = np.empty(6)
    clipped = np.empty(6)
    child_box = np.empty((2, 6))
    overlap_box = np.empty(6)
    root_area = 0.0
    cuts = 0
    n_out = 0
    next_free = 1
    task_node[0] = 0
    task_start[0] = 0
    task_end[0] = n
    sp = 1
    while sp > 0:
        sp -= 1
        node = task_node[sp]
        start = task_start[sp]
        end = task_end[sp]
        count = end - start
        _bounds(ref_box, start, end, box, centroid_box)
        for k in range(6):
            node_box[node, k] = box[k]
        area = box_area6(box)
        if node == 0:
            root_area = area
        kind = 0
        sah = np.inf
        axis = -1
        best_bin = -1
        scale = 0.0
        plane = 0.0
        if count > 1:
            axis, best_bin, sah, scale = _object_split(ref_box, start, end, centroid_box, bins, bin_box, bin_count,
                                                       right_area, acc, child_box)
            if axis >= 0:
                kind = 1
            overlapping = True
            for k in range(3):
                overlap_box[k] = max(child_box[0, k], child_box[1, k])
                overlap_box[k + 3] = min(child_box[0, k + 3], child_box[1, k + 3])
                overlapping = overlapping and overlap_box[k] <= overlap_box[k + 3]
            room = ((axis < 0 or (overlapping and box_area6(overlap_box) > alpha * root_area))
                    and cuts + count <= max_cuts and end + count <= capacity and next_free + 2 < node_capacity)
            if room:
                s_axis, s_plane, s_sah = _spatial_split(vertices, faces, ref_prim, ref_box, start, end, box, bins,
                                                        bin_box, bin_count, exits, right_area, acc, clipped)
                if s_axis >= 0 and s_sah < sah:
                    kind = 2
                    axis = s_axis
                    plane = s_plane
                    sah = s_sah
        split_cost = traversal_cost + intersection_cost * sah / max(area, 1e-300)
        if kind != 0 and count <= max_leaf_size and split_cost >= intersection_cost * count:
            kind = 0
        if kind == 0 and count > max_leaf_size:
            kind = 3
        mid = start
        right_start = start
        right_end = end
        if kind == 1:
            mid = _partition_objects(ref_prim, ref_box, start, end, axis, best_bin, centroid_box[axis], scale, bins)
            right_start = mid
        elif kind == 2:
            mid, right_end, cut = _partition_space(vertices, faces, ref_prim, ref_box, start, end, axis, plane, end,
                                                   clipped)
            right_start = end
            cuts += cut
            if mid == start or right_end == right_start:
                if mid == start:
                    start, end = right_start, right_end
                else:
                    end = mid
                count = end - start
                kind = 3 if count > max_leaf_size else 0
        if kind == 3:
            mid = (start + end) // 2
            right_start = mid
            right_end = end
        if kind == 0:
            node_first[node] = n_out
            node_count[node] = count
            for i in range(start, end):
                order[n_out] = ref_prim[i]
                n_out += 1
            continue
        left_node = next_free
        next_free += 2
        node_first[node] = left_node
        node_count[node] = 0
        task_node[sp] = left_node
        task_start[sp] = start
        task_end[sp] = mid
        task_node[sp + 1] = left_node + 1
        task_start[sp + 1] = right_start
        task_end[sp + 1] = right_end
        sp += 2
    return node_box[:next_free].copy(), node_first[:next_free].copy(), node_count[:next_free].copy(), order[:n_out].copy()


def build_sbvh(vertices, faces, lo, hi, max_leaf_size, bins, traversal_cost, intersection_cost, split_budget, alpha):
    """Build the SBVH over triangles ``faces`` of ``vertices`` (boxes ``lo``, ``hi``). Returns
    ``(node_box, node_first, node_count, order)`` as :func:`.build_top_down.build_top_down`
    does, except that ``order`` may name a triangle more than once (at most
    ``split_budget * len(faces)`` extra times)."""
    n = len(faces)
    return _build(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int64),
                  np.ascontiguousarray(lo, dtype=np.float64), np.ascontiguousarray(hi, dtype=np.float64),
                  int(max_leaf_size), int(bins), float(traversal_cost), float(intersection_cost),
                  int(split_budget * n), float(alpha))
