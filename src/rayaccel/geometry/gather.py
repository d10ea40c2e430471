"""Triangle corners gathered from an indexed mesh into the rows the intersection kernels read."""

from __future__ import annotations

from .._jit import kernel, on_threads

__all__ = ["gather_triangles"]


@kernel
def _gather(vertices, faces, order, out, first, end):
    for i in range(first, end):
        face = order[i]
        for corner in range(3):
            vertex = faces[face, corner]
            for k in range(3):
                out[i, 3 * corner + k] = vertices[vertex, k]


def gather_triangles(vertices, faces, order, out) -> None:
    """Write into ``out`` (n, 9) float64 the three vertices of face ``order[i]`` as row ``i``:
    numpy's ``vertices[faces[order]]`` in one pass split over the threads, without the index
    array in between, and into memory already in use where the caller has some (a refit:
    writing fresh pages cost 3x the gather itself here)."""
    on_threads(lambda first, end, _: _gather(vertices, faces, order, out, first, end), order.shape[0])
