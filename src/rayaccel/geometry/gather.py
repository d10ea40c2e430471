"""Triangles gathered from an indexed mesh in a structure's leaf order, in the smallest exact layout.

A BVH tests the triangles of a leaf one after the other, so it keeps them in
leaf order, apart from the scene. Two layouts hold them exactly:

* **rows**: an (n, 9) float32 array, each row a triangle's three corners, when
  every vertex of the mesh is a float32 number (binary PLY and STL files store
  float32): 36 bytes per triangle, read in one or two cache lines;
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
on the full dragon 1.00-1.06 (0.96-1.07 on two threads); the indexed layout on
the forest 0.97-1.01 and on the bunny 0.99-1.03.
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.extending import overload

from .._jit import kernel, on_threads, prefetch, unsigned

__all__ = ["gather_triangles", "layout_rows", "prim_count", "layout_nbytes", "corner", "prefetch_prim", "sphere_rows",
           "float32_exact"]


@kernel
def _gather_rows(vertices, faces, order, out, first, end):
    for i in range(first, end):
        face = order[i]
        for c in range(3):
            vertex = faces[face, c]
            for k in range(3):
                out[i, 3 * c + k] = vertices[vertex, k]


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
    """The triangles ``faces[order]`` over ``vertices`` in leaf order: float32 rows when
    ``exact_in_float32``, else the indexed layout (see the module docstring). Rows are
    written into ``out`` when it is rows of the same shape (a refit: writing fresh pages
    cost 3x the gather itself here)."""
    if exact_in_float32:
        if not (isinstance(out, np.ndarray) and out.dtype == np.float32 and out.shape == (len(order), 9)):
            out = np.empty((len(order), 9), dtype=np.float32)
        on_threads(lambda first, end, _: _gather_rows(vertices, faces, order, out, first, end), order.shape[0])
        return out
    leaf_id = np.full(len(vertices), -1, dtype=np.int64)
    corner_ids = np.empty((len(order), 3), dtype=np.int32)
    leaf_vertices = np.empty((_number_by_first_use(faces, order, leaf_id, corner_ids), 3))
    _place_vertices(vertices, leaf_id, leaf_vertices)
    return corner_ids, leaf_vertices


def layout_rows(geom) -> np.ndarray:
    """The triangles of a layout as (n, 9) float64 rows, for the passes that want whole rows
    (fitting a BVH's other bounding volumes); sphere rows as they are."""
    if isinstance(geom, tuple):
        corner_ids, vertices = geom
        return vertices[corner_ids].reshape(-1, 9)
    return geom.astype(np.float64)


def prim_count(geom) -> int:
    """How many primitives a layout holds."""
    return len(geom[0]) if isinstance(geom, tuple) else len(geom)


def layout_nbytes(geom) -> int:
    """Bytes of a layout: its array, or both arrays of the indexed one."""
    return int(sum(part.nbytes for part in geom)) if isinstance(geom, tuple) else int(geom.nbytes)


def corner(geom, prim, j, axis):
    """Coordinate ``axis`` of corner ``j`` of triangle ``prim`` in either layout, as a float."""
    if isinstance(geom, tuple):
        return float(geom[1][geom[0][prim, j], axis])
    return float(geom[prim, 3 * j + axis])


@overload(corner)
def _corner(geom, prim, j, axis):
    if isinstance(geom, types.Array):
        return lambda geom, prim, j, axis: np.float64(geom[unsigned(prim), unsigned(3 * j + axis)])
    return lambda geom, prim, j, axis: np.float64(geom[1][unsigned(geom[0][unsigned(prim), unsigned(j)]),
                                                                 unsigned(axis)])


def prefetch_prim(geom, prim):
    """Start loading what testing primitive ``prim`` reads first: its row, or its corner
    indices (prefetching its first vertex as well measured the same). A no-op outside kernels."""


@overload(prefetch_prim)
def _prefetch_prim(geom, prim):
    if isinstance(geom, types.Array):
        return lambda geom, prim: prefetch(geom, prim, 0)
    return lambda geom, prim: prefetch(geom[0], prim, 0)


def sphere_rows(geom):
    """``geom`` itself where it is rows (spheres: (n, 4)). A kernel that switches on the
    primitive kind at run time is typed with both branches; given the indexed triangle
    layout, its sphere branch, which never runs, sees the vertex array instead."""
    return geom[1] if isinstance(geom, tuple) else geom


@overload(sphere_rows)
def _sphere_rows(geom):
    if isinstance(geom, types.Array):
        return lambda geom: geom
    return lambda geom: geom[1]
