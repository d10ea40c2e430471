"""Point queries on a scene of instances: each instance asked in its own frame.

Closest point. An instance ``x -> A x + b`` whose linear part is a similarity
(``A = s R``, all singular values equal) maps distances by ``s`` exactly, so
the object's own walk by distance runs on ``A^-1 (p - b)`` with the search
radius divided by ``s``, and the object's closest point, mapped back, is the
world's. Under shear or non-uniform scale the object-space closest point is
not the world's; such an instance of a mesh is answered by a copy of its
triangles moved to the world, built with the same method on its first point
query and cached on the accelerator (``_world_copies``). Spheres under such a
transform are ellipsoids, whose closest point this library does not compute:
``closest_point``, ``distance`` and ``signed_distance`` raise
``NotImplementedError`` for them (``winding_number`` and ``contains`` work).
Instances are visited in id order, each only for the points whose distance
to its world box is within the best found so far; at equal distance the
lower instance id, then the lower primitive, wins.

Winding number. A triangle's solid angle is invariant under rotation,
translation and uniform scale and changes sign under reflection, and an
affine map moves the inside of a closed mesh to the inside of its image, so
an instance contributes ``sign(det A) w_obj(A^-1 (p - b))``; the scene's
winding number is the sum over instances (spheres: only points inside the
instance's box can lie inside it).
"""

from __future__ import annotations

import numpy as np

from ...scene import Spheres, TriangleMesh
from ..point_actions import empty_closest, finish_closest

__all__ = ["scene_nearest", "scene_closest_point", "scene_winding_number"]

_SIMILAR = 1e-12


def _box_distance2(points, lo, hi):
    gap = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    return np.einsum("ij,ij->i", gap, gap)


def _frame(accel, instance):
    """``(scale, object points map)``: the similarity scale (None otherwise) and a map to the object frame."""
    linear = accel.transforms[instance, :3, :3]
    singular = np.linalg.svd(linear, compute_uv=False)
    scale = float(singular[0]) if singular[0] - singular[-1] <= _SIMILAR * singular[0] else None
    inverse = accel.inverse[instance]
    return scale, lambda p: p @ inverse[:3, :3].T + inverse[:3, 3]


def _world_copy(accel, instance):
    """The instance's mesh moved to the world, built with the scene's method (cached)."""
    from ..registry import build

    copies = accel.__dict__.setdefault("_world_copies", {})
    if instance not in copies:
        obj = accel.objects[accel.instance_object[instance]].scene
        if isinstance(obj, Spheres):
            raise NotImplementedError(
                f"instance {instance} is a sphere set under shear or non-uniform scale (ellipsoids): its closest "
                "point is not implemented; winding_number and contains work")
        transform = accel.transforms[instance]
        vertices = obj.vertices @ transform[:3, :3].T + transform[:3, 3]
        copies[instance] = build(TriangleMesh(vertices, obj.faces), accel.method, **accel.options)
    return copies[instance]


def scene_nearest(accel, points, max_distance):
    """``(d2, prim, geom)``: each point's closest primitive over all instances within ``max_distance``."""
    n = len(points)
    best_d2 = np.full(n, max_distance * max_distance)
    best_prim = np.full(n, -1, dtype=np.int64)
    best_geom = np.full(n, -1, dtype=np.int64)
    for instance in range(len(accel.instance_object)):
        chosen = np.flatnonzero(_box_distance2(points, accel.world_lo[instance], accel.world_hi[instance]) <= best_d2)
        if not len(chosen):
            continue
        scale, to_object = _frame(accel, instance)
        if scale is None:
            target, local, factor = _world_copy(accel, instance), points[chosen], 1.0
        else:
            target, local, factor = accel.objects[accel.instance_object[instance]], to_object(points[chosen]), scale
        d2 = np.full(len(chosen), np.inf)
        prim = np.full(len(chosen), -1, dtype=np.int64)
        target._nearest(local, best_d2[chosen] / (factor * factor), d2, prim)
        d2 *= factor * factor
        better = (prim >= 0) & ((d2 < best_d2[chosen]) | (best_prim[chosen] < 0))
        keep = chosen[better]
        best_d2[keep], best_prim[keep], best_geom[keep] = d2[better], prim[better], instance
    return best_d2, best_prim, best_geom


def scene_closest_point(accel, points, max_distance):
    """:meth:`closest_point` fields ``(point, distance, prim, u, v, geom)`` of a scene."""
    from ...points import ClosestPoints

    point, distance, prim, u, v = empty_closest(len(points))
    _, best_prim, geom = scene_nearest(accel, points, max_distance)
    for instance in np.unique(geom[geom >= 0]):
        chosen = np.flatnonzero(geom == instance)
        scale, to_object = _frame(accel, instance)
        if scale is None:
            target, local = _world_copy(accel, instance), points[chosen]
        else:
            target, local = accel.objects[accel.instance_object[instance]], to_object(points[chosen])
        out = empty_closest(len(chosen))
        finish_closest(target.scene.kind, target.scene.geometry, local, best_prim[chosen], out[0], out[1], out[3],
                       out[4])
        transform = accel.transforms[instance]
        point[chosen] = out[0] if scale is None else out[0] @ transform[:3, :3].T + transform[:3, 3]
        distance[chosen] = out[1] * (1.0 if scale is None else scale)
        prim[chosen], u[chosen], v[chosen] = best_prim[chosen], out[3], out[4]
    return ClosestPoints(point, distance, prim, u, v, geom)


def scene_winding_number(accel, points, accuracy):
    """The scene's winding number: every instance's, signed by its orientation, summed."""
    total = np.zeros(len(points))
    for instance in range(len(accel.instance_object)):
        obj = accel.objects[accel.instance_object[instance]]
        if isinstance(obj.scene, Spheres):
            chosen = np.flatnonzero(_box_distance2(points, accel.world_lo[instance], accel.world_hi[instance]) == 0.0)
        else:
            chosen = np.arange(len(points))
        if not len(chosen):
            continue
        _, to_object = _frame(accel, instance)
        sign = np.sign(np.linalg.det(accel.transforms[instance, :3, :3]))
        total[chosen] += sign * obj._winding_number(np.ascontiguousarray(to_object(points[chosen])), accuracy)
    return total
