"""Fast winding numbers on a BVH (Barill, Dickson, Schmidt, Levin & Jacobson, "Fast Winding
Numbers for Soups and Clouds", SIGGRAPH 2018), first-order (dipole) expansion.

The winding number of a triangle soup at ``q`` is ``sum_t omega_t(q) / 4 pi``
(:mod:`rayaccel.geometry.winding`). For a set of triangles far from ``q`` it
is well approximated by the field of one dipole: ``(p~ - q) . N / (4 pi
|p~ - q|^3)``, with ``N`` the sum of the triangles' area-weighted normals
(half their edge cross products) and ``p~`` their area-weighted centroid.
Each node of a BVH -- which partitions the triangles, so every triangle
counts once -- stores ``N``, ``p~`` and ``r``, the radius of a ball around
``p~`` holding all its triangles. Evaluation walks down from the root: a node
with ``|q - p~| > beta r`` contributes its dipole; a leaf closer than that
contributes its triangles' exact solid angles. ``beta`` is the accuracy
parameter: larger is more exact and slower (``inf`` gives the exact sum);
the paper uses 2. The error of a node's dipole falls as ``1 / beta^2``
relative to its own contribution.

Spheres: a node's spheres contain ``q`` only if its box does, so the walk
descends only into boxes containing ``q`` and counts the spheres that hold it
(the spheres' "winding number", exact for any ``beta``).

Layout read: the binary BVH of :mod:`.layout` (``node_box`` float64,
``node_first``, ``node_count``) with the geometry in leaf order;
:func:`winding_moments` adds ``moments`` (n_nodes, 7): ``N`` (3), ``p~`` (3), ``r``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ..._jit import kernel, parallel_kernel, thread_id
from ...geometry.gather import corner
from ...geometry.kinds import TRIANGLE
from ...geometry.winding import prim_winding

__all__ = ["winding_moments", "fast_winding_kernel"]


@kernel
def _post_order(node_first, node_count):
    """Node indices with every node after its children."""
    order = np.empty(node_first.shape[0], dtype=np.int64)
    stack = [0]
    n = 0
    while len(stack) > 0:
        node = stack.pop()
        order[n] = node
        n += 1
        if node_count[node] == 0:
            stack.append(node_first[node])
            stack.append(node_first[node] + 1)
    return order[:n][::-1]


@kernel
def winding_moments(kind, geom, node_box, node_first, node_count):
    """Per-node dipole data (see the module docstring) of a BVH over ``geom`` in leaf order."""
    moments = np.zeros((node_first.shape[0], 7))
    if kind != TRIANGLE:
        return moments
    area = np.zeros(node_first.shape[0])
    for node in _post_order(node_first, node_count):
        nx = ny = nz = cx = cy = cz = a = 0.0
        if node_count[node] > 0:
            for k in range(node_first[node], node_first[node] + node_count[node]):
                ax, ay, az = corner(geom, k, 0, 0), corner(geom, k, 0, 1), corner(geom, k, 0, 2)
                bx, by, bz = corner(geom, k, 1, 0), corner(geom, k, 1, 1), corner(geom, k, 1, 2)
                qx, qy, qz = corner(geom, k, 2, 0), corner(geom, k, 2, 1), corner(geom, k, 2, 2)
                ex, ey, ez = bx - ax, by - ay, bz - az
                fx, fy, fz = qx - ax, qy - ay, qz - az
                tx, ty, tz = 0.5 * (ey * fz - ez * fy), 0.5 * (ez * fx - ex * fz), 0.5 * (ex * fy - ey * fx)
                ta = math.sqrt(tx * tx + ty * ty + tz * tz)
                nx, ny, nz, a = nx + tx, ny + ty, nz + tz, a + ta
                cx += ta * (ax + bx + qx) / 3.0
                cy += ta * (ay + by + qy) / 3.0
                cz += ta * (az + bz + qz) / 3.0
        else:
            for j in range(2):
                child = node_first[node] + j
                nx, ny, nz = nx + moments[child, 0], ny + moments[child, 1], nz + moments[child, 2]
                cx += area[child] * moments[child, 3]
                cy += area[child] * moments[child, 4]
                cz += area[child] * moments[child, 5]
                a += area[child]
        if a > 0.0:
            cx, cy, cz = cx / a, cy / a, cz / a
        else:
            cx = 0.5 * (node_box[node, 0] + node_box[node, 3])
            cy = 0.5 * (node_box[node, 1] + node_box[node, 4])
            cz = 0.5 * (node_box[node, 2] + node_box[node, 5])
        r2 = 0.0
        for box_corner in range(8):
            dx = node_box[node, 3 if box_corner & 1 else 0] - cx
            dy = node_box[node, 4 if box_corner & 2 else 1] - cy
            dz = node_box[node, 5 if box_corner & 4 else 2] - cz
            r2 = max(r2, dx * dx + dy * dy + dz * dz)
        moments[node] = (nx, ny, nz, cx, cy, cz, math.sqrt(r2))
        area[node] = a
    return moments


@parallel_kernel
def fast_winding_kernel(kind, geom, node_box, node_first, node_count, moments, points, beta, stack, out):
    """The winding number at each point (``out``), with far-field threshold ``beta``; ``stack``
    (threads, 2 * depth + 4) int64."""
    inv_4pi = 1.0 / (4.0 * math.pi)
    for i in prange(points.shape[0]):
        tid = thread_id()
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        total = 0.0
        stack[tid, 0] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            node = stack[tid, sp]
            if kind == TRIANGLE:
                dx, dy, dz = moments[node, 3] - px, moments[node, 4] - py, moments[node, 5] - pz
                d2 = dx * dx + dy * dy + dz * dz
                reach = beta * moments[node, 6]
                if d2 > reach * reach:
                    total += (dx * moments[node, 0] + dy * moments[node, 1] + dz * moments[node, 2]) * inv_4pi / (
                        d2 * math.sqrt(d2))
                    continue
            elif not (node_box[node, 0] <= px <= node_box[node, 3] and node_box[node, 1] <= py <= node_box[node, 4]
                      and node_box[node, 2] <= pz <= node_box[node, 5]):
                continue
            count = node_count[node]
            if count > 0:
                for k in range(node_first[node], node_first[node] + count):
                    total += prim_winding(kind, geom, k, px, py, pz)
            else:
                stack[tid, sp] = node_first[node]
                stack[tid, sp + 1] = node_first[node] + 1
                sp += 2
        out[i] = total
