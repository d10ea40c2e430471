"""rayaccel as trimesh's ray and proximity engine.

    import trimesh
    from rayaccel.integrations.trimesh import RayMeshIntersector, ProximityQuery

    mesh = trimesh.load("part.stl")
    mesh.ray = RayMeshIntersector(mesh)        # method="bvh-binned"; any ra.methods() name and its options
    mesh.nearest = ProximityQuery(mesh)

:class:`RayMeshIntersector` answers the calls of trimesh's Embree engine
(``trimesh.ray.ray_pyembree.RayMeshIntersector``) and :class:`ProximityQuery` those of
``trimesh.proximity.ProximityQuery``, with their argument names, defaults, return order,
shapes and dtypes, so that trimesh's own code that goes through ``mesh.ray`` and
``mesh.nearest`` runs on rayaccel too (``mesh.contains``, ``trimesh.proximity.longest_ray``,
``trimesh.registration``, ``trimesh.voxel.creation``). Both only translate arguments and
results around rayaccel's public queries (``intersect``, ``occluded``, ``intersect_all``,
``contains``, ``closest_point``, ``signed_distance``); inputs are validated by rayaccel's
validators and bad ones raise ``ValueError`` naming the problem.

Keeping up with the mesh
------------------------
The structure is built at the first query, not when the engine is made. trimesh stores
``mesh.vertices`` and ``mesh.faces`` as ``trimesh.caching.TrackedArray``, whose hash changes
after any write through the array (item assignment, in-place arithmetic, a view taken of
it) or a new assignment; trimesh's caches and engines key on these hashes
(``Cache(id_function=mesh.__hash__)``). Each query compares the faces' and the vertices'
hashes with those the structure was built for: new faces are built anew; new vertices under
the same faces refit a BVH method's boxes (``accel.refit``, Wald, Boulos & Shirley, ACM TOG
2007) and rebuild the other methods, and a BVH too once refitting has more than doubled its
SAH cost (:data:`REBUILD_COST_GROWTH`). A write that bypasses the tracking (through
``mesh.vertices.view(np.ndarray)``) is missed by trimesh's own caches and by this engine alike.

Both pickle and copy as trimesh's engines do: the built structure is left out of the pickle
and built again at the first query after loading, and ``copy.copy`` or ``copy.deepcopy``
returns a new engine over the same mesh object, with the same method and options, unbuilt.
When ``mesh.ray`` is a :class:`RayMeshIntersector` with the same method and options as a
:class:`ProximityQuery` over the same mesh, both use one structure.
"""

from __future__ import annotations

import numpy as np
from trimesh.caching import TrackedArray
from trimesh.constants import tol

from .._validate import as_points, as_positive_int
from ..scene import TriangleMesh
from ..structures.registry import build, methods

__all__ = ["RayMeshIntersector", "ProximityQuery", "REBUILD_COST_GROWTH"]

REBUILD_COST_GROWTH = 2.0
"""A refitted BVH whose SAH cost exceeds this multiple of its build's is built anew instead."""


def _content_hash(array) -> int:
    """The hash trimesh keeps for a ``TrackedArray`` (recomputed only after a write), or the
    hash of the bytes of any other array."""
    if isinstance(array, TrackedArray):
        return hash(array)
    return hash(np.ascontiguousarray(array).tobytes())


def _as_array(name: str, values) -> np.ndarray:
    """``values`` as a float64 (n, 3) array (n = 0 allowed), ``ValueError`` otherwise; NaN and
    inf are left to the query, which names them."""
    try:
        return as_points(name, values, allow_empty=True, check_finite=False)
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def _rays(ray_origins, ray_directions) -> tuple[np.ndarray, np.ndarray]:
    origins = _as_array("ray_origins", ray_origins)
    directions = _as_array("ray_directions", ray_directions)
    if origins.shape != directions.shape:
        raise ValueError(f"ray_origins {origins.shape} and ray_directions {directions.shape} must have the same shape")
    return origins, directions


def _points(points) -> np.ndarray:
    try:
        return as_points("points", points, allow_empty=True)
    except TypeError as exc:
        raise ValueError(str(exc)) from None


class _TrackedStructure:
    """A rayaccel structure over a trimesh mesh's current triangles, built at the first
    :meth:`get` and kept current by the hashes of ``mesh.faces`` and ``mesh.vertices`` (see the
    module docstring). With ``over_vertices`` its primitives are the vertices instead, each as
    the degenerate triangle ``(i, i, i)``, whose closest point is the vertex itself, so that
    ``closest_point`` finds the nearest vertex and its index.
    """

    def __init__(self, mesh, method: str, options: dict, refit: bool, over_vertices: bool = False):
        if method not in methods():
            raise ValueError(f"unknown method {method!r}; choose one of {', '.join(methods())}")
        self.mesh = mesh
        self.method = method
        self.options = options
        self.refit = bool(refit)
        self.over_vertices = over_vertices
        self._accel = None
        self._key = None

    def get(self):
        """The structure over the mesh as it is now: built, refitted or kept."""
        vertices = self.mesh.vertices
        faces_key = len(vertices) if self.over_vertices else _content_hash(self.mesh.faces)
        key = (faces_key, _content_hash(vertices))
        if self._accel is not None and key == self._key:
            return self._accel
        if self._accel is not None and self.refit and faces_key == self._key[0] and self._refitted(vertices):
            self._key = key
            return self._accel
        vertices = np.array(vertices, dtype=np.float64)
        if self.over_vertices:
            faces = np.repeat(np.arange(len(vertices), dtype=np.int64), 3).reshape(-1, 3)
        else:
            faces = self.mesh.faces
        self._accel = build(TriangleMesh(vertices, faces), self.method, **self.options)
        self._key = key
        return self._accel

    def _refitted(self, vertices) -> bool:
        """Refit the structure to ``vertices``; False when their number changed, its method cannot
        refit, or refitting grew its SAH cost beyond :data:`REBUILD_COST_GROWTH` times the build's."""
        if len(vertices) != len(self._accel.scene.vertices):
            return False
        try:
            self._accel.refit(np.array(vertices, dtype=np.float64))
        except NotImplementedError:
            return False
        return self._accel.sah_cost() <= REBUILD_COST_GROWTH * self._accel.sah_cost_at_build

    def __getstate__(self):
        state = self.__dict__.copy()
        state.update(_accel=None, _key=None)
        return state


class RayMeshIntersector:
    """Ray queries on a trimesh mesh with rayaccel: the interface of
    ``trimesh.ray.ray_pyembree.RayMeshIntersector``.

    Parameters
    ----------
    geometry : trimesh.Trimesh
        The mesh, kept as :attr:`mesh`; the structure follows its vertices and faces
        (module docstring).
    method : str
        Any name of ``rayaccel.methods()``; the default BVH traces fastest here.
    refit : bool
        Refit a BVH when only the vertices moved (``False``: always build anew).
    **options
        The method's options (``help(rayaccel.build_class(method))``).

    Rays are traced in float64 from ``t = 0``; directions need not be unit length but must
    not be zero, and coordinates must be finite (``ValueError`` otherwise).
    """

    def __init__(self, geometry, method: str = "bvh-binned", *, refit: bool = True, **options):
        self.mesh = geometry
        self.method = method
        self.options = options
        self._structure = _TrackedStructure(geometry, method, options, refit)

    @property
    def accelerator(self):
        """The rayaccel structure over the mesh as it is now (built or refitted on access)."""
        return self._structure.get()

    def intersects_id(self, ray_origins, ray_directions, multiple_hits: bool = True, max_hits=100,
                      return_locations: bool = False):
        """The triangles each ray hits, with every hit or only the first.

        Parameters
        ----------
        ray_origins, ray_directions : (n, 3) float
            The rays.
        multiple_hits : bool
            Every hit along each ray, or only the first.
        max_hits : int or None
            At most this many hits per ray, the nearest (None: all).
        return_locations : bool
            Also return the hit points.

        Returns
        -------
        index_tri : (m,) int64
            The triangle (index of ``mesh.faces``) of each hit.
        index_ray : (m,) int64
            The ray of each hit.
        locations : (m, 3) float64
            ``origin + t * direction`` of each hit; only with ``return_locations``.

        The hits are every crossing of rayaccel's ``intersect_all``: each triangle a ray crosses
        once, a crossing through an edge or vertex shared by several triangles once (given to
        one of them by a tie-break rule, so that a closed mesh is crossed an odd number of
        times from inside), in float64, grouped by ray in ray order and sorted by distance
        along each ray (equal distances by triangle). trimesh's Embree engine differs: it casts
        float32 rays and, after each hit, casts again from the hit moved along the ray by
        ``max(1e-8, 1e-6 * mesh.scale)``, so that it misses a surface closer than that behind a
        hit; a crossing of a shared edge or vertex can come back once per triangle there; the
        offset doubles while the same triangle comes back (its guard against a ray stuck on
        a triangle that float32 cannot step past); and its hits are grouped by depth (all
        first hits, then all second hits). Its ``max_hits`` bounds those
        re-casts; here it keeps each ray's ``max_hits`` nearest hits.
        """
        origins, directions = _rays(ray_origins, ray_directions)
        if max_hits is not None:
            try:
                max_hits = as_positive_int("max_hits", max_hits)
            except TypeError as exc:
                raise ValueError(str(exc)) from None
        if len(origins) == 0:
            index_tri, index_ray, t = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        elif multiple_hits:
            hits = self._structure.get().intersect_all(origins, directions, max_hits=max_hits)
            index_tri, index_ray, t = hits.prim, hits.ray, hits.t
        else:
            hits = self._structure.get().intersect(origins, directions)
            index_ray = np.flatnonzero(hits.prim >= 0)
            index_tri, t = hits.prim[index_ray], hits.t[index_ray]
        if not return_locations:
            return index_tri, index_ray
        locations = origins[index_ray]
        locations += t[:, None] * directions[index_ray]
        return index_tri, index_ray, locations

    def intersects_location(self, ray_origins, ray_directions, multiple_hits: bool = True):
        """Where the rays hit the mesh: ``(locations (m, 3) float64, index_ray (m,) int64,
        index_tri (m,) int64)``, the hits of :meth:`intersects_id`."""
        index_tri, index_ray, locations = self.intersects_id(ray_origins, ray_directions,
                                                             multiple_hits=multiple_hits, return_locations=True)
        return locations, index_ray, index_tri

    def intersects_first(self, ray_origins, ray_directions):
        """(n,) int32: the first triangle each ray hits, -1 where it hits none (int32 as
        trimesh's Embree engine returns it)."""
        origins, directions = _rays(ray_origins, ray_directions)
        if len(origins) == 0:
            return np.zeros(0, dtype=np.int32)
        return self._structure.get().intersect(origins, directions).prim.astype(np.int32)

    def intersects_any(self, ray_origins, ray_directions):
        """(n,) bool: whether each ray hits the mesh (an any-hit walk, which stops at the
        first triangle it finds)."""
        origins, directions = _rays(ray_origins, ray_directions)
        if len(origins) == 0:
            return np.zeros(0, dtype=bool)
        return self._structure.get().occluded(origins, directions)

    def contains_points(self, points):
        """(n,) bool: whether each point is inside the mesh, by the generalized winding number
        (rayaccel's ``contains``: ``|w| > 0.5``; see :mod:`rayaccel.structures.ray_winding`).

        trimesh's engines count the crossings of a ray each way from the point and cast again
        in a random direction where the two disagree; the winding number counts one ray's
        crossings signed by the side they leave through, adds the caps over the mesh's holes,
        gives the same answer on a closed mesh away from its surface, and stays right where the
        mesh has holes or duplicated triangles, which break parity. Points on the surface are
        undecided either way.
        """
        points = _points(points)
        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        return self._structure.get().contains(points)

    def __copy__(self):
        return RayMeshIntersector(self.mesh, self.method, refit=self._structure.refit, **self.options)

    def __deepcopy__(self, memo):
        return self.__copy__()


class ProximityQuery:
    """Closest points, nearest vertices and signed distances on a trimesh mesh with rayaccel:
    the interface of ``trimesh.proximity.ProximityQuery``.

    Parameters as for :class:`RayMeshIntersector`. When ``mesh.ray`` is a
    :class:`RayMeshIntersector` with the same method and options, its structure is used.
    """

    def __init__(self, mesh, method: str = "bvh-binned", *, refit: bool = True, **options):
        self._mesh = mesh
        self.method = method
        self.options = options
        self._structure = _TrackedStructure(mesh, method, options, refit)
        self._vertex_structure = _TrackedStructure(mesh, method, options, refit, over_vertices=True)

    def _accelerator(self):
        ray = getattr(self._mesh, "ray", None)
        if (isinstance(ray, RayMeshIntersector) and ray.mesh is self._mesh and ray.method == self.method
                and ray.options == self.options):
            return ray._structure.get()
        return self._structure.get()

    def on_surface(self, points):
        """The closest point of the mesh's surface to each point.

        Returns
        -------
        closest : (n, 3) float64
            The closest surface point.
        distance : (n,) float64
            Its distance.
        triangle_id : (n,) int64
            The triangle it lies on; where several are equally close (the point is closest to
            a shared edge or vertex), the lowest index. trimesh instead takes, of the two
            nearest candidates, the one whose normal faces the point more.
        """
        points = _points(points)
        if len(points) == 0:
            return np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int64)
        closest = self._accelerator().closest_point(points)
        return closest.point, closest.distance, closest.prim

    def vertex(self, points):
        """The nearest vertex to each point: ``(distance (n,) float64, vertex_id (n,) int64)``,
        the lowest index among equally near ones; scalars for a single point given as (3,),
        as trimesh's ``cKDTree`` query returns them. Every vertex counts, referenced by a face
        or not, as in trimesh. The vertices get their own structure (the module docstring's
        degenerate triangles), built at the first call.
        """
        single = np.ndim(points) == 1
        points = _points(points)
        if len(points) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        closest = self._vertex_structure.get().closest_point(points)
        if single:
            return closest.distance[0], closest.prim[0]
        return closest.distance, closest.prim

    def signed_distance(self, points):
        """(n,) float64: the distance from each point to the surface, with trimesh's sign:
        positive inside the mesh, negative outside, and positive within ``trimesh.tol.merge``
        of the surface. This is the opposite of rayaccel's ``accel.signed_distance`` (negative
        inside); inside is decided by the winding number, as in
        :meth:`RayMeshIntersector.contains_points`.
        """
        points = _points(points)
        if len(points) == 0:
            return np.zeros(0)
        signed = self._accelerator().signed_distance(points)
        np.negative(signed, out=signed)
        near = np.abs(signed) <= tol.merge
        signed[near] = np.abs(signed[near])
        return signed
