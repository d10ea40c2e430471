"""k-DOPs (discrete oriented polytopes): the 14-DOP's normals and its surface area.

A k-DOP is the intersection of k/2 slabs ``lo_j <= n_j . x <= hi_j`` with fixed
normals (Kay & Kajiya 1986; Klosowski, Held, Mitchell, Sowizral & Zikan,
"Efficient Collision Detection Using Bounding Volume Hierarchies of k-DOPs",
IEEE TVCG 4(1), 1998). The 14-DOP here uses the three axes and the four cube
diagonals; with only the first three it is the axis-aligned box.

The surface area, which the SAH statistics need, is the sum of the areas of
its faces: each face is a large square in its plane clipped by the other 13
half-spaces (Sutherland & Hodgman 1974).
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import kernel

__all__ = ["KDOP_NORMALS", "kdop_surface_areas"]

KDOP_NORMALS = np.array([
    [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
    [1.0, 1.0, 1.0], [1.0, 1.0, -1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0],
])


@kernel
def _clip(poly, n_in, out, ax, ay, az, b):
    """Keep the part of polygon ``poly[:n_in]`` with ``a . x <= b``; returns the new vertex count."""
    n_out = 0
    for i in range(n_in):
        j = (i + 1) % n_in
        di = ax * poly[i, 0] + ay * poly[i, 1] + az * poly[i, 2] - b
        dj = ax * poly[j, 0] + ay * poly[j, 1] + az * poly[j, 2] - b
        if di <= 0.0:
            out[n_out] = poly[i]
            n_out += 1
        if (di < 0.0 < dj) or (dj < 0.0 < di):
            s = di / (di - dj)
            for k in range(3):
                out[n_out, k] = poly[i, k] + s * (poly[j, k] - poly[i, k])
            n_out += 1
    return n_out


@kernel
def kdop_surface_areas(volume, normals):
    """Surface area of each k-DOP ``volume[i] = (lo_0..lo_{m-1}, hi_0..hi_{m-1})`` over ``normals`` (m, 3)."""
    m = normals.shape[0]
    n = volume.shape[0]
    areas = np.zeros(n)
    planes = np.empty((2 * m, 4))
    poly = np.empty((4 + 2 * m + 2, 3))
    scratch = np.empty((4 + 2 * m + 2, 3))
    for node in range(n):
        reach = 0.0
        for j in range(m):
            planes[j, 0:3] = normals[j]
            planes[j, 3] = volume[node, j + m]
            planes[j + m, 0:3] = -normals[j]
            planes[j + m, 3] = -volume[node, j]
            reach = max(reach, abs(volume[node, j]), abs(volume[node, j + m]))
        size = 4.0 * reach + 1.0
        total = 0.0
        for f in range(2 * m):
            ax, ay, az = planes[f, 0], planes[f, 1], planes[f, 2]
            length = math.sqrt(ax * ax + ay * ay + az * az)
            ux, uy, uz = ax / length, ay / length, az / length
            px, py, pz = ux * planes[f, 3] / length, uy * planes[f, 3] / length, uz * planes[f, 3] / length
            # two unit tangents of the face's plane
            if abs(ux) < 0.9:
                tx, ty, tz = 0.0, uz, -uy
            else:
                tx, ty, tz = -uz, 0.0, ux
            tl = math.sqrt(tx * tx + ty * ty + tz * tz)
            tx, ty, tz = tx / tl, ty / tl, tz / tl
            sx, sy, sz = uy * tz - uz * ty, uz * tx - ux * tz, ux * ty - uy * tx
            count = 4
            for c in range(4):
                a = size if c == 0 or c == 3 else -size
                b = size if c < 2 else -size
                poly[c, 0] = px + a * tx + b * sx
                poly[c, 1] = py + a * ty + b * sy
                poly[c, 2] = pz + a * tz + b * sz
            for g in range(2 * m):
                if g != f and count > 0:
                    count = _clip(poly, count, scratch, planes[g, 0], planes[g, 1], planes[g, 2], planes[g, 3])
                    poly[:count] = scratch[:count]
            cx = cy = cz = 0.0
            for i in range(count):
                j = (i + 1) % count
                cx += poly[i, 1] * poly[j, 2] - poly[i, 2] * poly[j, 1]
                cy += poly[i, 2] * poly[j, 0] - poly[i, 0] * poly[j, 2]
                cz += poly[i, 0] * poly[j, 1] - poly[i, 1] * poly[j, 0]
            total += 0.5 * abs(cx * ux + cy * uy + cz * uz)
        areas[node] = total
    return areas
