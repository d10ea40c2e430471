"""The generalized winding number of a triangle mesh from one ray per point.

The winding number of a closed mesh about a point off it is an integer: the
number of times a ray from the point to infinity leaves the mesh through a
triangle's front minus the times it leaves through a back (the degree of the
projection; Jacobson, Kavan & Sorkine-Hornung, "Robust Inside-Outside
Segmentation using Generalized Winding Numbers", SIGGRAPH 2013, section 3).
The counting walk gives each crossing of a shared edge or vertex to exactly
one triangle (:func:`rayaccel.geometry.triangle.cross_triangle`), so the sum is
exact on every ray, also through edges and vertices.

A mesh with holes is closed by caps over them (:mod:`rayaccel.geometry.caps`):
with ``S`` the mesh and ``K`` its caps, ``w_S(q) = w_{S+K}(q) - w_K(q)``. The
first term is the signed crossings of the ray with ``S`` (the accelerator's own
walk) and with ``K``; the second is the fast winding number of the caps alone
(Barill et al. 2018, :mod:`rayaccel.structures.bvh.fast_winding`), whose
approximation error is confined to the surroundings of the holes; with
``accuracy=inf`` it is the exact sum and so is the result. A closed mesh needs
no caps and one ray per point. Where the caps would be a large part of the mesh
(a triangle soup without shared vertices), the fast winding number of the mesh
itself is used instead.

Each point casts its ray towards the nearest side of the scene's box, the
shortest way out, tilted off the axis by a small fixed amount (multiples of
a power of two, so that a test can aim a ray exactly at a vertex or an edge).
On the surface itself the winding number jumps; there a ray starting exactly
on a triangle counts that crossing half, and a point a rounding error off the
surface gets the value of the side it lies on.
"""

from __future__ import annotations

import numpy as np

from ..geometry.caps import boundary_caps
from ..rays import RayBatch
from .actions import signed_crossings

__all__ = ["ray_winding_number", "escape_directions", "MAX_CAP_FRACTION"]

MAX_CAP_FRACTION = 0.25
"""Largest ratio of cap triangles to mesh triangles for which the caps are used."""

_TILT = np.array([3.0, 5.0, 7.0]) / 512.0


def escape_directions(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n, 3) directions from each point towards the nearest side of the box ``[lo, hi]`` (away from
    the box for points outside it), slightly tilted off the axis."""
    below, above = points - lo, hi - points
    upwards = above < below
    np.minimum(below, above, out=below)
    rows, axis = np.arange(len(points)), np.argmin(below, axis=1)
    directions = np.empty_like(points)
    directions[:] = _TILT
    directions[rows, axis] = np.where(upwards[rows, axis], 1.0, -1.0)
    return directions


def ray_winding_number(accel, points: np.ndarray, accuracy: float) -> np.ndarray:
    """(n,) winding number about validated ``points`` of the triangle mesh of ``accel``, by the
    signed crossings of one ray per point (see the module docstring)."""
    caps = _caps(accel)
    if caps is False:
        return accel._fast_winding(points, accuracy)
    directions = escape_directions(points, *accel.scene_box)
    rays = RayBatch(points, directions, np.zeros(len(points)), np.full(len(points), np.inf),
                    np.arange(len(points), dtype=np.int64))
    halves = _signed_crossings(accel, rays)
    winding = 0.5 * halves
    if caps is not None:
        winding += 0.5 * _signed_crossings(caps, rays) - caps._fast_winding(points, accuracy)
    return winding


def _signed_crossings(accel, rays) -> np.ndarray:
    halves = np.zeros(len(rays.origins), dtype=np.int64)
    accel._trace(accel._ordered(rays, True), False, signed_crossings(halves), None)
    return halves


def _caps(accel):
    """The accelerator over the caps of ``accel``'s mesh (None when it is closed, False when the caps
    would be too large to help), built on first use and cached on ``accel``."""
    cached = accel.__dict__.get("_caps_cache")
    if cached is not None:
        return cached[0]
    from ..scene import TriangleMesh
    from .registry import build

    mesh = accel.scene
    cap_vertices, cap_faces = boundary_caps(mesh.vertices, mesh.faces)
    if len(cap_faces) == 0:
        caps = None
    elif len(cap_faces) > MAX_CAP_FRACTION * len(mesh.faces):
        caps = False
    else:
        caps = build(TriangleMesh(cap_vertices, cap_faces), "bvh-binned")
    accel._caps_cache = (caps,)
    return caps
