"""Bounding volumes for BVH nodes besides boxes: spheres and 14-DOPs, fitted to a built tree.

* k-DOP (Kay & Kajiya 1986 "slabs"; Klosowski et al., IEEE TVCG 1998): the
  interval of projections onto each of 7 fixed normals (3 axes, 4 cube
  diagonals). Fitting over the primitives and over the child volumes give
  the same intervals, so nodes are fitted bottom-up from their children.
* Sphere: fitted over the primitives below the node with Ritter's algorithm
  ("An Efficient Bounding Sphere", Graphics Gems, 1990; within about 5-20 % of
  the minimal radius), or over the two child spheres with the exact sphere
  enclosing both (``fit="children"``), cheaper to build and looser.

A node's primitives are contiguous in leaf order, ``prim_order[lo : hi]``,
which :func:`node_ranges` finds for every node.
"""

from __future__ import annotations

import math

import numpy as np

from ..._jit import kernel
from ...scene import TRIANGLE

__all__ = ["node_ranges", "fit_kdops", "fit_spheres"]


@kernel
def node_ranges(node_first, node_count):
    """``(range_lo, range_hi)``: each node's primitives in leaf order."""
    n = node_first.shape[0]
    range_lo = np.empty(n, dtype=np.int64)
    range_hi = np.empty(n, dtype=np.int64)
    for node in range(n - 1, -1, -1):  # children have larger indices than their parent
        if node_count[node] > 0:
            range_lo[node] = node_first[node]
            range_hi[node] = node_first[node] + node_count[node]
        else:
            range_lo[node] = min(range_lo[node_first[node]], range_lo[node_first[node] + 1])
            range_hi[node] = max(range_hi[node_first[node]], range_hi[node_first[node] + 1])
    return range_lo, range_hi


@kernel
def _prim_slabs(kind, geom, normals):
    n = geom.shape[0]
    k = normals.shape[0]
    slabs = np.empty((n, 2 * k))
    for p in range(n):
        for j in range(k):
            nx, ny, nz = normals[j, 0], normals[j, 1], normals[j, 2]
            if kind == TRIANGLE:
                a = geom[p, 0] * nx + geom[p, 1] * ny + geom[p, 2] * nz
                b = geom[p, 3] * nx + geom[p, 4] * ny + geom[p, 5] * nz
                c = geom[p, 6] * nx + geom[p, 7] * ny + geom[p, 8] * nz
                slabs[p, j] = min(a, b, c)
                slabs[p, j + k] = max(a, b, c)
            else:
                center = geom[p, 0] * nx + geom[p, 1] * ny + geom[p, 2] * nz
                reach = geom[p, 3] * math.sqrt(nx * nx + ny * ny + nz * nz)
                slabs[p, j] = center - reach
                slabs[p, j + k] = center + reach
    return slabs


@kernel
def fit_kdops(kind, geom_sorted, node_first, node_count, normals):
    """(n_nodes, 2k) slab intervals: minima for the k normals, then maxima."""
    prim_slabs = _prim_slabs(kind, geom_sorted, normals)
    k = normals.shape[0]
    n = node_first.shape[0]
    volume = np.empty((n, 2 * k))
    for node in range(n - 1, -1, -1):
        for j in range(k):
            volume[node, j] = np.inf
            volume[node, j + k] = -np.inf
        if node_count[node] > 0:
            for p in range(node_first[node], node_first[node] + node_count[node]):
                for j in range(k):
                    volume[node, j] = min(volume[node, j], prim_slabs[p, j])
                    volume[node, j + k] = max(volume[node, j + k], prim_slabs[p, j + k])
        else:
            for child in range(node_first[node], node_first[node] + 2):
                for j in range(k):
                    volume[node, j] = min(volume[node, j], volume[child, j])
                    volume[node, j + k] = max(volume[node, j + k], volume[child, j + k])
    return volume


@kernel
def _distance(centers, i, x, y, z):
    return math.sqrt((centers[i, 0] - x) ** 2 + (centers[i, 1] - y) ** 2 + (centers[i, 2] - z) ** 2)


@kernel
def _farthest(centers, radii, start, end, x, y, z):
    best = -1.0
    far = start
    for i in range(start, end):
        d = _distance(centers, i, x, y, z) + radii[i]
        if d > best:
            best = d
            far = i
    return far


@kernel
def _ritter(centers, radii, start, end):
    """Ritter's bounding sphere of the balls ``centers[start:end]`` with ``radii``."""
    a = _farthest(centers, radii, start, end, centers[start, 0], centers[start, 1], centers[start, 2])
    b = _farthest(centers, radii, start, end, centers[a, 0], centers[a, 1], centers[a, 2])
    cx = 0.5 * (centers[a, 0] + centers[b, 0])
    cy = 0.5 * (centers[a, 1] + centers[b, 1])
    cz = 0.5 * (centers[a, 2] + centers[b, 2])
    r = 0.5 * _distance(centers, a, centers[b, 0], centers[b, 1], centers[b, 2]) + max(radii[a], radii[b])
    for i in range(start, end):
        d = _distance(centers, i, cx, cy, cz)
        if d + radii[i] > r:
            new_r = 0.5 * (r + d + radii[i])
            if d > 0.0:
                shift = (new_r - r) / d
                cx += shift * (centers[i, 0] - cx)
                cy += shift * (centers[i, 1] - cy)
                cz += shift * (centers[i, 2] - cz)
            r = new_r
    return cx, cy, cz, r


@kernel
def _enclose_two(a, b):
    d = math.sqrt((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2 + (b[2] - a[2]) ** 2)
    if d + b[3] <= a[3]:
        return a[0], a[1], a[2], a[3]
    if d + a[3] <= b[3]:
        return b[0], b[1], b[2], b[3]
    r = 0.5 * (d + a[3] + b[3])
    s = (r - a[3]) / d
    return a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * (b[2] - a[2]), r


@kernel
def fit_spheres(kind, geom_sorted, node_first, node_count, over_children):
    """(n_nodes, 4) bounding spheres ``(cx, cy, cz, r)``, each grown by a relative 1e-9 for rounding."""
    if kind == TRIANGLE:
        centers = geom_sorted.reshape(-1, 3).copy()
        radii = np.zeros(centers.shape[0])
        per_prim = 3
    else:
        centers = geom_sorted[:, :3].copy()
        radii = geom_sorted[:, 3].copy()
        per_prim = 1
    range_lo, range_hi = node_ranges(node_first, node_count)
    n = node_first.shape[0]
    volume = np.empty((n, 4))
    for node in range(n - 1, -1, -1):
        if over_children and node_count[node] == 0:
            cx, cy, cz, r = _enclose_two(volume[node_first[node]], volume[node_first[node] + 1])
        else:
            cx, cy, cz, r = _ritter(centers, radii, range_lo[node] * per_prim, range_hi[node] * per_prim)
        scale = abs(cx) + abs(cy) + abs(cz) + r
        volume[node, 0] = cx
        volume[node, 1] = cy
        volume[node, 2] = cz
        volume[node, 3] = r + 1e-9 * scale
    return volume
