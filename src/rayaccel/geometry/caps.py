"""Caps over the holes of a triangle mesh: a few triangles that make it closed.

The boundary of a mesh is the chain of its directed edges (each triangle
``(a, b, c)`` gives ``a->b``, ``b->c``, ``c->a``) in which an edge and its
reverse cancel; the edges left over run around the holes, and in every
vertex as many of them arrive as leave (a boundary has no boundary). For
each boundary edge ``a->b`` the cap holds the triangle ``(c, b, a)``, with
``c`` the mean of the boundary vertices connected to ``a``: its edge ``b->a``
cancels the hole's edge, and its two edges to ``c`` cancel those of the
neighbouring cap triangles, since every vertex has as many leaving edges as
arriving ones. The mesh and its caps together have no boundary, so their
winding number is an integer about every point off them; each cap is a fan
inside the convex hull of its hole, so it is small where the holes are small.

Vertices are identified by their coordinates (scans and STL files often
repeat a vertex once per triangle), and an edge that a duplicated or flipped
triangle uses more often one way than the other stays in the boundary as
many times as it is unbalanced.
"""

from __future__ import annotations

import numpy as np

__all__ = ["boundary_caps"]


def boundary_caps(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(cap_vertices, cap_faces)``: triangles whose union with the mesh ``(vertices, faces)`` has
    no boundary (see the module docstring); no triangles for a closed mesh."""
    points, same = _merged(vertices)
    corners = same[faces]
    tails, heads = corners.ravel(), np.roll(corners, -1, axis=1).ravel()
    proper = tails != heads
    tails, heads = tails[proper], heads[proper]
    keys, balance = _edge_balance(np.minimum(tails, heads) * len(points) + np.maximum(tails, heads), tails < heads)
    open_edges = balance != 0
    low, high = np.divmod(keys[open_edges], len(points))
    balance = balance[open_edges]
    tails = np.repeat(np.where(balance > 0, low, high), np.abs(balance))
    heads = np.repeat(np.where(balance > 0, high, low), np.abs(balance))
    if len(tails) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    rim, local = np.unique(np.concatenate([tails, heads]), return_inverse=True)
    tail, head = local[:len(tails)], local[len(tails):]
    hole = _components(len(rim), tail, head)
    holes, hole = np.unique(hole, return_inverse=True)
    apex = np.zeros((len(holes), 3))
    np.add.at(apex, hole, points[rim])
    apex /= np.bincount(hole, minlength=len(holes))[:, None]
    cap_vertices = np.concatenate([points[rim], apex])
    cap_faces = np.stack([len(rim) + hole[tail], head, tail], axis=1)
    return cap_vertices, cap_faces


def _merged(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(points, same)``: the distinct rows of ``vertices`` in lexicographic order and, for each
    vertex, the index of its row there (``np.unique(..., axis=0)``, a few times faster)."""
    order = np.lexsort(vertices.T[::-1])
    ordered = vertices[order]
    new = np.ones(len(vertices), dtype=bool)
    np.any(ordered[1:] != ordered[:-1], axis=1, out=new[1:])
    same = np.empty(len(vertices), dtype=np.int64)
    same[order] = np.cumsum(new) - 1
    return ordered[new], same


def _edge_balance(keys: np.ndarray, forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(distinct keys, balance)``: per undirected edge key, how many more times it is used
    forward than backward, from one sort of the keys with the direction as their lowest bit."""
    tagged = np.sort(keys * 2 + forward)
    if len(tagged) == 0:
        return keys[:0], keys[:0]
    starts = np.flatnonzero(np.concatenate([[True], tagged[1:] != tagged[:-1]]))
    runs = np.diff(np.append(starts, len(tagged))) * np.where(tagged[starts] & 1, 1, -1)
    run_keys = tagged[starts] >> 1
    first = np.flatnonzero(np.concatenate([[True], run_keys[1:] != run_keys[:-1]]))
    return run_keys[first], np.add.reduceat(runs, first)


def _components(n: int, tail: np.ndarray, head: np.ndarray) -> np.ndarray:
    """A label per vertex ``0..n-1``, equal for vertices joined by edges ``tail[i]-head[i]``:
    the smallest index of the component, by label propagation with pointer jumping."""
    label = np.arange(n)
    while True:
        lowest = np.minimum(label[tail], label[head])
        before = label.copy()
        np.minimum.at(label, tail, lowest)
        np.minimum.at(label, head, lowest)
        label = label[label]
        if np.array_equal(label, before):
            return label
