"""Scenes of many objects: meshes and sphere sets placed by affine transforms, shared as instances.

A :class:`Scene` holds *objects* (each distinct mesh or sphere set once) and
*instances* (an object and a 4 x 4 affine transform from the object's frame
to the world). Adding the same object again adds an instance, not a copy:
``ra.build(scene, method)`` builds one structure per object, however often it
is placed, and a top-level BVH over the instances' world boxes
(:mod:`rayaccel.structures.instanced`), the two-level scheme of Embree's
instances and pbrt-v4's ``TransformedPrimitive`` / ``BVHAggregate``.
"""

from __future__ import annotations

import numpy as np

from .geometry.kinds import SPHERE
from .scene import PrimitiveBounds, Spheres, TriangleMesh

__all__ = ["Scene", "as_transform", "transform_boxes"]

# Largest condition number of a transform's linear part: rays mapped through a worse
# inverse lose too many digits for the hits to match the world-space geometry.
_MAX_CONDITION = 1e12


def as_transform(transform) -> np.ndarray:
    """``transform`` as a float64 (4, 4) affine matrix acting on column vectors ``(x, y, z, 1)``:
    None is the identity; a (3, 4) matrix gets the row ``0, 0, 0, 1``. The matrix must be
    finite, affine (last row ``0, 0, 0, 1``) and invertible with a condition number below 1e12."""
    if transform is None:
        return np.eye(4)
    try:
        matrix = np.array(transform, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"transform must be a 4x4 array of numbers: {exc}") from None
    if matrix.shape == (3, 4):
        matrix = np.vstack((matrix, [0.0, 0.0, 0.0, 1.0]))
    if matrix.shape != (4, 4):
        raise ValueError(f"transform must have shape (4, 4) or (3, 4), got {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise ValueError("transform contains NaN or infinite values")
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"transform must be affine (last row 0, 0, 0, 1), got last row {matrix[3].tolist()}")
    condition = np.linalg.cond(matrix[:3, :3])
    if not condition < _MAX_CONDITION:
        raise ValueError(f"transform is singular or nearly so (condition number {condition:.3g})")
    return matrix


def transform_boxes(lo: np.ndarray, hi: np.ndarray, transforms: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World boxes ``(lo, hi)`` (n, 3) around the boxes ``lo[i]..hi[i]`` moved by ``transforms[i]``
    (n, 4, 4): the box of the eight transformed corners (Arvo, "Transforming Axis-Aligned
    Bounding Boxes", Graphics Gems 1990, in its corner form)."""
    corners = np.stack([np.where(np.array(bits, bool), hi, lo) for bits in np.ndindex(2, 2, 2)], axis=1)
    world = np.einsum("nij,nkj->nki", transforms[:, :3, :3], corners) + transforms[:, None, :3, 3]
    return world.min(axis=1), world.max(axis=1)


def _as_object(geometry):
    if isinstance(geometry, (TriangleMesh, Spheres)):
        return geometry
    try:
        import trimesh
    except ImportError:  # pragma: no cover - trimesh is a dependency
        trimesh = None
    if trimesh is not None and isinstance(geometry, trimesh.Trimesh):
        return TriangleMesh(geometry.vertices, geometry.faces)
    raise TypeError(f"a scene holds TriangleMesh, Spheres or trimesh.Trimesh objects, got {type(geometry).__name__}")


class Scene:
    """Objects placed in a world by affine transforms.

    >>> scene = ra.Scene()
    >>> tree = scene.add(tree_mesh)                         # id 0, the identity transform
    >>> scene.add(tree_mesh, transform=T)                   # id 1: the same object again, an instance
    >>> accel = ra.build(scene, "bvh-binned")               # one BVH for the tree, however often placed
    >>> accel.intersect(o, d).geom                          # which id was hit, -1 on a miss

    Objects are told apart by identity: adding the very same object (a
    ``TriangleMesh``, ``Spheres`` or ``trimesh.Trimesh``) again shares its
    structure; an equal copy is a new object.
    """

    def __init__(self):
        self.objects: list[TriangleMesh | Spheres] = []
        self._sources: list = []  # what was added, kept alive so that ids stay unique
        self._object_of_source: dict[int, int] = {}
        self._instance_object: list[int] = []
        self._transforms: list[np.ndarray] = []
        self._local_boxes: list[tuple[np.ndarray, np.ndarray]] = []

    def add(self, geometry, transform=None) -> int:
        """Place ``geometry`` in the scene with ``transform`` (4 x 4 affine: rotation, scale,
        shear, translation; the identity when None) and return its id, the ``hits.geom``
        of rays that hit it. The same object added again becomes an instance sharing its
        structure."""
        matrix = as_transform(transform)
        key = id(geometry)
        if key not in self._object_of_source:
            obj = _as_object(geometry)
            self._object_of_source[key] = len(self.objects)
            self._sources.append(geometry)
            self.objects.append(obj)
            bounds = obj.bounds()
            self._local_boxes.append((bounds.scene_lo, bounds.scene_hi))
        self._instance_object.append(self._object_of_source[key])
        self._transforms.append(matrix)
        return len(self._transforms) - 1

    def set_transform(self, gid: int, transform) -> None:
        """Move instance ``gid``; a structure built earlier sees it after ``accel.refit()``."""
        self._transforms[self._check_id(gid)] = as_transform(transform)

    def transform(self, gid: int) -> np.ndarray:
        """The (4, 4) transform of instance ``gid`` (a copy)."""
        return self._transforms[self._check_id(gid)].copy()

    def _check_id(self, gid) -> int:
        if isinstance(gid, bool) or not isinstance(gid, (int, np.integer)):
            raise TypeError(f"an instance id is an int, got {type(gid).__name__}")
        if not 0 <= gid < len(self._transforms):
            raise IndexError(f"no instance {gid}; the scene has {len(self._transforms)}")
        return int(gid)

    @property
    def n_instances(self) -> int:
        return len(self._transforms)

    @property
    def instance_object(self) -> np.ndarray:
        """(n_instances,) int64: the object each instance places."""
        return np.array(self._instance_object, dtype=np.int64)

    @property
    def transforms(self) -> np.ndarray:
        """(n_instances, 4, 4) float64: each instance's object-to-world transform."""
        return np.array(self._transforms).reshape(-1, 4, 4)

    def __len__(self) -> int:
        """Primitives in the world, every instance counted."""
        return int(sum(len(self.objects[o]) for o in self._instance_object))

    def __repr__(self) -> str:
        return f"Scene({len(self.objects)} objects, {self.n_instances} instances, {len(self):,} primitives)"

    def _require_instances(self) -> None:
        if not self._transforms:
            raise ValueError("the scene is empty: add an object first")

    def world_boxes(self, instance_object=None, transforms=None) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)`` (n_instances, 3): each instance's box in the world, for the given
        placements (the scene's own when None)."""
        self._require_instances()
        instance_object = self.instance_object if instance_object is None else instance_object
        transforms = self.transforms if transforms is None else transforms
        local_lo = np.array([box[0] for box in self._local_boxes])[instance_object]
        local_hi = np.array([box[1] for box in self._local_boxes])[instance_object]
        return transform_boxes(local_lo, local_hi, transforms)

    def bounds(self) -> PrimitiveBounds:
        """Boxes of the instances (not of their primitives), and the box around them all."""
        lo, hi = self.world_boxes()
        return PrimitiveBounds(lo, hi, lo.min(axis=0), hi.max(axis=0), lambda: 0.5 * (lo + hi))

    def flatten(self) -> TriangleMesh | Spheres:
        """Every instance copied into world coordinates as one mesh (or one sphere set, when
        every object is spheres and every transform keeps them round). Primitives follow
        instance by instance in id order. For comparisons: a flattened scene costs the
        memory instancing saves."""
        self._require_instances()
        kinds = {obj.kind for obj in self.objects}
        if len(kinds) > 1:
            raise ValueError("a scene of meshes and spheres together cannot be flattened into one")
        parts = []
        for o, matrix in zip(self._instance_object, self._transforms):
            obj, linear = self.objects[o], matrix[:3, :3]
            if obj.kind == SPHERE:
                scale = abs(np.linalg.det(linear)) ** (1.0 / 3.0)
                if not np.allclose(linear.T @ linear, scale * scale * np.eye(3), rtol=0, atol=1e-12 * scale * scale):
                    raise ValueError("a sphere instance with non-uniform scale or shear is an ellipsoid")
                parts.append((obj.centers @ linear.T + matrix[:3, 3], obj.radii * scale))
            else:
                parts.append((obj.vertices @ linear.T + matrix[:3, 3], obj.faces))
        if SPHERE in kinds:
            return Spheres(np.concatenate([c for c, _ in parts]), np.concatenate([r for _, r in parts]))
        offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
        return TriangleMesh(np.concatenate([v for v, _ in parts]),
                            np.concatenate([f + offset for (_, f), offset in zip(parts, offsets)]))
