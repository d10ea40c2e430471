"""Eight-wide traversal layout of a BVH: the binary tree collapsed, eight child boxes per node.

Dammertz, Hanika & Keller, "Shallow Bounding Volume Hierarchies for Fast
SIMD Ray Tracing of Incoherent Rays", EGSR 2008, and Ernst & Greiner,
"Multi Bounding Volume Hierarchies", IEEE Symposium on Interactive Ray
Tracing 2008; eight wide as Embree's BVH8 on AVX (Wald et al., "Embree: A
Kernel Framework for Efficient CPU Ray Tracing", ACM TOG 33(4), 2014). Every
builder still writes the binary layout of :mod:`.layout`; this is derived from
it for box traversal. A wide node takes the two children of a binary node and,
while it holds fewer than eight, replaces the inner child of largest surface
area by that child's two children. A ray then fetches one 256-byte record (four
cache lines) and tests eight boxes per step. Against four children per node,
measured on the full dragon: 30 % fewer nodes visited per ray (incoherent
rays 6.7 against 9.5, camera rays 2.9 against 4.1), 4.8 MB more records
(22.8 against 18.0 MB: the nodes at the bottom of the tree have free slots).

``wide_records`` (n_wide, 64) float32, 64-byte aligned, one record per node:

* columns ``8 j + c`` for ``j`` in 0..5: component ``j`` (lo_x, lo_y, lo_z,
  hi_x, hi_y, hi_z) of child ``c``'s box, rounded outwards to float32;
* column ``48 + c`` (read as int32): child ``c``'s wide node index, or for a
  leaf child the offset of its first primitive in ``prim_order``;
* column ``56 + c`` (read as int32): 0 for an inner child, the primitive count
  of a leaf child, -1 for an unused slot, whose box is empty (lo = +inf,
  hi = -inf), so that no ray enters it and the traversal needs no test for it.

Node 0 is the root; a binary tree that is a single leaf becomes a root with
one leaf child. A forest (the grid-BVH hybrid's cells' trees) collapses the
same way, tree ``k`` rooted at wide node ``k``.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import prange, types
from numba.extending import intrinsic

from ..._jit import emit_prefetch, inline_kernel, kernel, parallel_kernel
from ..._memory import cache_line_aligned

__all__ = ["WIDTH", "RECORD", "LINK", "COUNT", "child_link", "child_count", "is_record_array", "record_row",
           "prefetch_record", "wide_tree", "wide_records", "wide_depth"]

WIDTH = 8
RECORD = 8 * WIDTH
"""Numbers (float32 or int32) in a wide record."""
LINK = 6 * WIDTH
"""Column of child 0's link in a record."""
COUNT = 7 * WIDTH
"""Column of child 0's primitive count in a record."""
UNUSED = -1


def is_record_array(records_type) -> bool:
    """Whether Numba's type ``records_type`` is that of a C-contiguous 2-D array, which
    :func:`record_row` can address (the walks' intrinsics refuse to compile for others)."""
    return isinstance(records_type, types.Array) and records_type.ndim == 2 and records_type.layout == "C"


def record_row(context, builder, records_type, records, node, node_type):
    """The IR of the address of wide record ``node``'s first number in ``records``, an (n, RECORD)
    C-contiguous array: its data pointer plus ``node * RECORD``, a shift. Numba's own indexing
    multiplies the row by the array's stride, read at run time, which put a multiplication (and
    the stride's reload from the stack) on the path from one node to the next."""
    view = context.make_array(records_type)(context, builder, records)
    intp = context.get_value_type(types.intp)
    index = builder.mul(context.cast(builder, node, node_type, types.intp), ir.Constant(intp, RECORD))
    return builder.gep(view.data, [index], inbounds=True)


@intrinsic
def _record_number(typingctx, records, node, column):
    """``records[node, column]`` of an (n, RECORD) C-contiguous array, addressed by
    :func:`record_row`."""
    if not is_record_array(records):
        return None
    signature = records.dtype(records, node, column)

    def codegen(context, builder, sig, args):
        row = record_row(context, builder, sig.args[0], args[0], args[1], sig.args[1])
        offset = context.cast(builder, args[2], sig.args[2], types.intp)
        return builder.load(builder.gep(row, [offset], inbounds=True))

    return signature, codegen


@intrinsic
def prefetch_record(typingctx, records, node):
    """Start loading the four cache lines of wide record ``node`` (:func:`rayaccel._jit.prefetch`),
    addressed by :func:`record_row`."""
    if not is_record_array(records):
        return None
    signature = types.void(records, node)

    def codegen(context, builder, sig, args):
        row = record_row(context, builder, sig.args[0], args[0], args[1], sig.args[1])
        intp = context.get_value_type(types.intp)
        for line in range(0, RECORD, 16):
            emit_prefetch(builder, builder.gep(row, [ir.Constant(intp, line)], inbounds=True))
        return context.get_dummy_value()

    return signature, codegen


@inline_kernel
def child_link(links, node, c):
    """Child ``c``'s link in wide record ``node`` of ``links`` (the records seen as int32): the
    wide node it is, or the leaf order row of its first primitive."""
    return _record_number(links, node, LINK + c)


@inline_kernel
def child_count(links, node, c):
    """Child ``c``'s primitive count in wide record ``node``: 0 for an inner node."""
    return _record_number(links, node, COUNT + c)


@kernel
def _box_area(node_box, node):
    ex = node_box[node, 3] - node_box[node, 0]
    ey = node_box[node, 4] - node_box[node, 1]
    ez = node_box[node, 5] - node_box[node, 2]
    return ex * ey + ey * ez + ez * ex


@kernel
def _collapse(node_box, node_first, node_count, roots):
    """For each wide node, the binary nodes in its child slots (-1 where unused) and,
    for inner ones, the wide node each becomes; the binary trees rooted at ``roots`` become
    the wide trees rooted at 0, 1, ..., each tree's other nodes in one run after the roots.
    A wide node stands for an inner binary node or a root, which bounds their number, and
    only the rows used are written: full dragon, 7 ms, where filling int64 rows for every
    binary node and converting them to int32 took 50 ms."""
    capacity = 1 + roots.shape[0]
    for binary in range(node_count.shape[0]):
        if node_count[binary] == 0:
            capacity += 1
    slots = np.empty((capacity, WIDTH), dtype=np.int32)
    child_wide = np.zeros((capacity, WIDTH), dtype=np.int32)
    pending_wide = np.empty(capacity, dtype=np.int64)
    pending_binary = np.empty(capacity, dtype=np.int64)
    n_wide = roots.shape[0]
    for tree in range(roots.shape[0]):
        pending_wide[0] = tree
        pending_binary[0] = roots[tree]
        n_pending = 1
        while n_pending > 0:
            n_pending -= 1
            wide = pending_wide[n_pending]
            binary = pending_binary[n_pending]
            slots[wide] = -1
            if node_count[binary] > 0:
                slots[wide, 0] = binary
                continue
            slots[wide, 0] = node_first[binary]
            slots[wide, 1] = node_first[binary] + 1
            used = 2
            while used < WIDTH:
                widest = -1
                widest_area = -1.0
                for c in range(used):
                    if node_count[slots[wide, c]] == 0:
                        area = _box_area(node_box, slots[wide, c])
                        if area > widest_area:
                            widest, widest_area = c, area
                if widest < 0:
                    break
                opened = slots[wide, widest]
                for c in range(used, widest + 1, -1):
                    slots[wide, c] = slots[wide, c - 1]
                slots[wide, widest] = node_first[opened]
                slots[wide, widest + 1] = node_first[opened] + 1
                used += 1
            for c in range(used):
                if node_count[slots[wide, c]] == 0:
                    pending_wide[n_pending] = n_wide
                    pending_binary[n_pending] = slots[wide, c]
                    n_pending += 1
                    child_wide[wide, c] = n_wide
                    n_wide += 1
    return slots[:n_wide], child_wide[:n_wide]


@inline_kernel
def _float32_outward(exact, upper):
    """``exact`` rounded to a float32 no smaller (``upper``) or no larger than it. One step of
    ``exact``'s own size in float32 ulps (2**-23 of it) moves past any rounding in the wrong
    direction; ``nextafter`` (a library call, most of the packing time when called for every
    box face) is left for values too small for that step."""
    rounded = np.float32(exact)
    if upper and rounded < exact:
        rounded = np.float32(exact + abs(exact) * 2.0 ** -23)
        if rounded < exact:
            rounded = np.nextafter(rounded, np.float32(np.inf))
    elif not upper and rounded > exact:
        rounded = np.float32(exact - abs(exact) * 2.0 ** -23)
        if rounded > exact:
            rounded = np.nextafter(rounded, np.float32(-np.inf))
    return rounded


@parallel_kernel
def _pack(slots, child_wide, node_box, node_first, node_count, records, links):
    for wide in prange(slots.shape[0]):
        for c in range(WIDTH):
            binary = slots[wide, c]
            if binary < 0:
                for j in range(3):
                    records[wide, WIDTH * j + c] = np.inf
                    records[wide, WIDTH * (j + 3) + c] = -np.inf
                links[wide, COUNT + c] = UNUSED
                continue
            for j in range(6):
                records[wide, WIDTH * j + c] = _float32_outward(node_box[binary, j], j >= 3)
            inner = node_count[binary] == 0
            links[wide, LINK + c] = child_wide[wide, c] if inner else node_first[binary]
            links[wide, COUNT + c] = 0 if inner else node_count[binary]


def wide_tree(node_box: np.ndarray, node_first: np.ndarray, node_count: np.ndarray,
              roots: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The collapse of a binary BVH: ``(slots, child_wide)``, each (n_wide, WIDTH) int32, the binary
    node in each wide node's slot (-1 where unused) and the wide node an inner one becomes. A forest
    of binary trees rooted at ``roots`` (default: one tree rooted at 0) becomes one of wide trees,
    tree ``k`` rooted at wide node ``k``."""
    roots = np.zeros(1, dtype=np.int64) if roots is None else np.asarray(roots, dtype=np.int64)
    return _collapse(node_box, node_first, node_count, roots)


def wide_records(node_box: np.ndarray, node_first: np.ndarray, node_count: np.ndarray, tree=None) -> np.ndarray:
    """The wide records (see the module docstring) of a binary BVH. ``tree``, the
    :func:`wide_tree` of the same binary tree, skips the collapse: a refit moves the boxes,
    not the tree (full dragon: the collapse is about a third of the records' time)."""
    slots, child_wide = wide_tree(node_box, node_first, node_count) if tree is None else tree
    n_wide = len(slots)
    records = cache_line_aligned((n_wide, 8 * WIDTH), np.float32)
    _pack(slots, child_wide, node_box, node_first, node_count, records, records.view(np.int32))
    return records


@kernel
def wide_depth(slots, child_wide, node_count):
    """Depth of the deepest wide node (root 0) of a collapse whose inner children follow
    their parents."""
    depth = np.zeros(slots.shape[0], dtype=np.int64)
    for wide in range(slots.shape[0]):
        for c in range(WIDTH):
            binary = slots[wide, c]
            if binary >= 0 and node_count[binary] == 0:
                depth[child_wide[wide, c]] = depth[wide] + 1
    return depth.max()
