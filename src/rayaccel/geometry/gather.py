"""Triangle corners gathered from an indexed mesh into the rows the intersection kernels read."""

from __future__ import annotations

from numba import prange

from .._jit import parallel_kernel

__all__ = ["gather_triangles"]


@parallel_kernel
def gather_triangles(vertices, faces, order, out):
    """Write into ``out`` (n, 9) float64 the three vertices of face ``order[i]`` as row ``i``:
    numpy's ``vertices[faces[order]]`` in one parallel pass, without the index array in
    between, and into memory already in use where the caller has some (a refit: writing
    fresh pages cost 3x the gather itself here)."""
    for i in prange(order.shape[0]):
        face = order[i]
        for corner in range(3):
            vertex = faces[face, corner]
            for k in range(3):
                out[i, 3 * corner + k] = vertices[vertex, k]
