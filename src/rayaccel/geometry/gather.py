"""Triangles gathered from an indexed mesh in a structure's leaf order, in the smallest exact layout.

A BVH tests the triangles of a leaf one after the other, so it keeps them in
leaf order, apart from the scene. Two layouts hold them exactly:

* **lanes**: when every vertex of the mesh is a float32 number (binary PLY and
  STL files store float32), an (ceil(n / 4), 9, 4) float32 array: triangle ``i``
  is lane ``i % 4`` of group ``i // 4``, whose row ``3 j + k`` holds coordinate
  ``k`` of corner ``j`` of its four triangles (the lanes past the last triangle
  repeat it). That is 36 bytes per triangle, as rows of nine floats take, with
  each coordinate of four consecutive triangles in 16 bytes, which one vector
  instruction loads: Embree's ``Triangle4`` leaves (Wald et al., "Embree: A
  Kernel Framework for Efficient CPU Ray Tracing", ACM TOG 33(4), 2014), for
  the edge test of four triangles at once (:mod:`.triangle_lanes`);
* **indexed**: ``(corner_ids, leaf_vertices)`` otherwise: the mesh's vertices
  (float64) renumbered in the order the leaves first use them, and an (n, 3)
  int32 array of each triangle's corners in that numbering: 12 bytes per
  triangle and 24 per vertex, about 24 bytes per triangle on a closed mesh
  (half as many vertices as triangles), against 72 for float64 rows. The
  vertices of a leaf's triangles lie next to each other, since the leaf uses
  them first.

Kernels read both through :func:`corner`, which Numba resolves by the layout's
type when it compiles, and which always gives float64: arithmetic on corners
stays float64 whichever layout holds them, so the triangle test computes the
same values bit for bit. Measured against float64 rows (72 bytes per
triangle), same hits, one thread, medians of 7 interleaved rounds, in every
column (camera, incoherent and shadow rays, closest and any hit): float32 rows
(the lanes' predecessor, (n, 9), read one triangle at a time) on the full dragon
1.00-1.06 (0.96-1.07 on two threads); the indexed layout on the forest
0.97-1.01 and on the bunny 0.99-1.03. The lanes against those rows: see
:func:`rayaccel.structures.bvh.traverse_wide.visit_leaf` and the README.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

from .._jit import kernel, on_threads, prefetch, unsigned

__all__ = ["LANES", "LANE_BITS", "gather_triangles", "layout_rows", "prim_count", "layout_nbytes", "corner",
           "prefetch_prim", "sphere_rows", "float32_exact", "is_lanes", "is_lanes_type", "lane_pointer"]

LANE_BITS = 2
LANES = 1 << LANE_BITS
"""Triangles a group of the lanes layout holds: their float64 coordinates fill an AVX2 register.
Triangle ``k`` is lane ``k & (LANES - 1)`` of group ``k >> LANE_BITS``."""
_GROUP_FLOATS = 9 * LANES


@kernel
def _gather_lanes(vertices, faces, order, out, first_group, end_group):
    last = order.shape[0] - 1
    for group in range(first_group, end_group):
        for lane in range(LANES):
            face = order[min(LANES * group + lane, last)]
            for c in range(3):
                vertex = faces[face, c]
                for k in range(3):
                    out[group, 3 * c + k, lane] = vertices[vertex, k]


@kernel
def _number_by_first_use(faces, order, leaf_id, corner_ids):
    """Number the vertices in the order the faces ``order`` first use them (``leaf_id``,
    arriving -1) and write each face's corners in that numbering; returns how many there are."""
    n_used = 0
    for i in range(order.shape[0]):
        face = order[i]
        for c in range(3):
            vertex = faces[face, c]
            if leaf_id[vertex] < 0:
                leaf_id[vertex] = n_used
                n_used += 1
            corner_ids[i, c] = leaf_id[vertex]
    return n_used


@kernel
def _place_vertices(vertices, leaf_id, leaf_vertices):
    for vertex in range(vertices.shape[0]):
        row = leaf_id[vertex]
        if row >= 0:
            for k in range(3):
                leaf_vertices[row, k] = vertices[vertex, k]


def float32_exact(vertices: np.ndarray) -> bool:
    """Whether every coordinate is a float32 number (so a float32 copy loses nothing)."""
    return bool(np.array_equal(vertices.astype(np.float32), vertices))


def gather_triangles(vertices, faces, order, exact_in_float32: bool, out=None):
    """The triangles ``faces[order]`` over ``vertices`` in leaf order: the lanes layout when
    ``exact_in_float32``, else the indexed layout (see the module docstring). Lanes are
    written into ``out`` when it is lanes of the same shape (a refit: writing fresh pages
    cost 3x the gather itself here)."""
    if exact_in_float32:
        shape = (-(-len(order) // LANES), 9, LANES)
        if not (isinstance(out, np.ndarray) and out.dtype == np.float32 and out.shape == shape):
            out = np.empty(shape, dtype=np.float32)
        on_threads(lambda first, end, _: _gather_lanes(vertices, faces, order, out, first, end), shape[0])
        return out
    leaf_id = np.full(len(vertices), -1, dtype=np.int64)
    corner_ids = np.empty((len(order), 3), dtype=np.int32)
    leaf_vertices = np.empty((_number_by_first_use(faces, order, leaf_id, corner_ids), 3))
    _place_vertices(vertices, leaf_id, leaf_vertices)
    return corner_ids, leaf_vertices


def layout_rows(geom) -> np.ndarray:
    """The triangles of a layout as (n, 9) float64 rows, for the passes that want whole rows
    (fitting a BVH's other bounding volumes); sphere rows as they are. The lanes layout gives
    a row for each of its lanes, the last group's padding among them."""
    if isinstance(geom, tuple):
        corner_ids, vertices = geom
        return vertices[corner_ids].reshape(-1, 9)
    if is_lanes(geom):
        return np.ascontiguousarray(geom.transpose(0, 2, 1).reshape(-1, 9), dtype=np.float64)
    return geom.astype(np.float64)


def prim_count(geom) -> int:
    """How many primitives a layout holds (in the lanes layout, its lanes: the last group's
    padding repeats the last triangle)."""
    if isinstance(geom, tuple):
        return len(geom[0])
    return len(geom) * LANES if is_lanes(geom) else len(geom)


def layout_nbytes(geom) -> int:
    """Bytes of a layout: its array, or both arrays of the indexed one."""
    return int(sum(part.nbytes for part in geom)) if isinstance(geom, tuple) else int(geom.nbytes)


def is_lanes(geom) -> bool:
    """Whether ``geom`` is the lanes layout; in a kernel, a constant of its type."""
    return isinstance(geom, np.ndarray) and geom.ndim == 3


def is_lanes_type(geom_type) -> bool:
    """Whether ``geom_type``, a layout's Numba type, is the lanes layout's (for overloads and intrinsics)."""
    return isinstance(geom_type, types.Array) and geom_type.ndim == 3


@overload(is_lanes)
def _is_lanes(geom):
    lanes = is_lanes_type(geom)
    return lambda geom: lanes


def lane_pointer(context, builder, lanes_type, lanes_value, group, row):
    """The LLVM pointer (float*) to row ``row`` of group ``group`` (i64 values) of a lanes
    layout: its four lanes' coordinate, at a constant stride of :data:`LANES` floats a row and
    ``9 * LANES`` a group, where Numba's indexing would multiply by the shape read at run time."""
    array = context.make_array(lanes_type)(context, builder, lanes_value)
    int64 = ir.IntType(64)
    offset = builder.add(builder.mul(group, int64(_GROUP_FLOATS)), builder.mul(row, int64(LANES)))
    return builder.gep(array.data, [offset])


def corner(geom, prim, j, axis):
    """Coordinate ``axis`` of corner ``j`` of triangle ``prim`` in either layout, as a float."""
    if isinstance(geom, tuple):
        return float(geom[1][geom[0][prim, j], axis])
    if is_lanes(geom):
        return float(geom[prim // LANES, 3 * j + axis, prim % LANES])
    return float(geom[prim, 3 * j + axis])


@overload(corner)
def _corner(geom, prim, j, axis):
    if is_lanes_type(geom):
        return lambda geom, prim, j, axis: np.float64(_stored_lane_coordinate(geom, prim, 3 * j + axis))
    if isinstance(geom, types.Array):
        return lambda geom, prim, j, axis: np.float64(geom[unsigned(prim), unsigned(3 * j + axis)])
    return lambda geom, prim, j, axis: np.float64(geom[1][unsigned(geom[0][unsigned(prim), unsigned(j)]),
                                                                 unsigned(axis)])


def stored_corner(geom, prim, j, axis):
    """:func:`corner` as the layout stores it: float32 in the lanes layout, float64 otherwise."""
    if is_lanes(geom):
        return geom[prim // LANES, 3 * j + axis, prim % LANES]
    return corner(geom, prim, j, axis)


@overload(stored_corner)
def _stored_corner(geom, prim, j, axis):
    if is_lanes_type(geom):
        return lambda geom, prim, j, axis: _stored_lane_coordinate(geom, prim, 3 * j + axis)
    return lambda geom, prim, j, axis: corner(geom, prim, j, axis)


@intrinsic
def _stored_lane_coordinate(typingctx, lanes, prim, row):
    """Row ``row`` (coordinate ``k`` of corner ``j`` at ``3 j + k``) of triangle ``prim`` in a lanes
    layout, float32 as stored."""
    signature = types.float32(lanes, prim, row)

    def codegen(context, builder, sig, args):
        prim_value = context.cast(builder, args[1], sig.args[1], types.int64)
        row_value = context.cast(builder, args[2], sig.args[2], types.int64)
        int64 = ir.IntType(64)
        pointer = lane_pointer(context, builder, sig.args[0], args[0], builder.lshr(prim_value, int64(LANE_BITS)),
                               row_value)
        return builder.load(builder.gep(pointer, [builder.and_(prim_value, int64(LANES - 1))]))

    return signature, codegen


def prefetch_prim(geom, prim):
    """Start loading what testing primitive ``prim`` reads first: its row, the three cache
    lines of its group of lanes, or its corner indices (prefetching its first vertex as well
    measured the same). A no-op outside kernels."""


@overload(prefetch_prim)
def _prefetch_prim(geom, prim):
    if is_lanes_type(geom):
        def prefetch_group(geom, prim):
            group = geom[unsigned(prim >> LANE_BITS)]
            prefetch(group, 0, 0)
            prefetch(group, 4, 0)
            prefetch(group, 8, 0)
        return prefetch_group
    if isinstance(geom, types.Array):
        return lambda geom, prim: prefetch(geom, prim, 0)
    return lambda geom, prim: prefetch(geom[0], prim, 0)


def sphere_rows(geom):
    """``geom`` itself where it is rows (spheres: (n, 4)). A kernel that switches on the
    primitive kind at run time is typed with both branches; given a triangle layout, its
    sphere branch, which never runs, sees a 2-D array of it instead (the indexed layout's
    vertices, the lanes layout's first group)."""
    return geom[1] if isinstance(geom, tuple) else geom


@overload(sphere_rows)
def _sphere_rows(geom):
    if is_lanes_type(geom):
        return lambda geom: geom[0]
    if isinstance(geom, types.Array):
        return lambda geom: geom
    return lambda geom: geom[1]
