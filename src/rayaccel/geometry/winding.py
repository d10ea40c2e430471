"""The generalized winding number (Jacobson, Kavan & Sorkine-Hornung, "Robust Inside-Outside
Segmentation using Generalized Winding Numbers", SIGGRAPH 2013), exactly.

A triangle ``a, b, c`` seen from ``p`` subtends the signed solid angle of
Van Oosterom & Strackee, "The Solid Angle of a Plane Triangle", IEEE Trans.
Biomedical Engineering 30(2), 1983:
``tan(omega / 2) = A . (B x C) / (|A||B||C| + (A.B)|C| + (A.C)|B| + (B.C)|A|)`` with
``A = a - p`` etc., positive when ``p`` lies behind the triangle's
counter-clockwise face (inside a closed, outward-oriented mesh). The winding
number is the sum of the solid angles over ``4 pi``: 1 inside a closed
outward mesh, 0 outside, fractional near holes, -1 inside an inverted one.
On the surface itself it is undefined (this gives +-1/2 on a face, 0 at a
vertex).

For spheres the "winding number" is the number of spheres containing the
point (strictly inside, ``|p - c| < r``): each sphere is a closed surface of
winding number 1 inside.
"""

from __future__ import annotations

import math

from .._jit import inline_kernel
from .gather import corner, sphere_rows
from .kinds import TRIANGLE

__all__ = ["solid_angle", "prim_winding"]


@inline_kernel
def solid_angle(geom, row, px, py, pz):
    """Signed solid angle of triangle ``row`` of ``geom`` seen from ``p``."""
    ax, ay, az = corner(geom, row, 0, 0) - px, corner(geom, row, 0, 1) - py, corner(geom, row, 0, 2) - pz
    bx, by, bz = corner(geom, row, 1, 0) - px, corner(geom, row, 1, 1) - py, corner(geom, row, 1, 2) - pz
    cx, cy, cz = corner(geom, row, 2, 0) - px, corner(geom, row, 2, 1) - py, corner(geom, row, 2, 2) - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    ab = ax * bx + ay * by + az * bz
    ac = ax * cx + ay * cy + az * cz
    bc = bx * cx + by * cy + bz * cz
    return 2.0 * math.atan2(det, la * lb * lc + ab * lc + ac * lb + bc * la)


@inline_kernel
def prim_winding(kind, geom, row, px, py, pz):
    """Primitive ``row``'s share of the winding number at ``p``: its solid angle over 4 pi
    (triangles), 1 or 0 (spheres: inside or not)."""
    if kind == TRIANGLE:
        return solid_angle(geom, row, px, py, pz) / (4.0 * math.pi)
    spheres = sphere_rows(geom)
    fx, fy, fz = px - spheres[row, 0], py - spheres[row, 1], pz - spheres[row, 2]
    return 1.0 if fx * fx + fy * fy + fz * fz < spheres[row, 3] * spheres[row, 3] else 0.0
