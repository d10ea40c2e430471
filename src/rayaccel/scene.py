"""Scenes: triangle meshes and spheres, mesh loading, built-in and procedural scenes.

A scene hands the rest of the library three things, all flat arrays:

* ``bounds()`` -- per-primitive boxes ``lo``, ``hi`` and ``centroid`` (n, 3) and the
  scene's box, the only thing builders see;
* ``kind`` -- :data:`TRIANGLE` or :data:`SPHERE`;
* ``geometry`` -- the per-primitive data the intersection kernels read: for
  triangles the three vertices as one row of 9 floats, for spheres
  ``(cx, cy, cz, radius)``.
"""

from __future__ import annotations

import functools
import gzip
import io
import os
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from ._validate import as_index_triples, as_points, as_positive_int
from .geometry.bounds import primitive_bounds, sphere_centroids, triangle_centroids
from .geometry.gather import float32_exact, gather_triangles
from .geometry.kinds import SPHERE, TRIANGLE

__all__ = [
    "TRIANGLE",
    "SPHERE",
    "TriangleMesh",
    "Spheres",
    "MeshLoadError",
    "load_mesh",
    "random_spheres",
]


class MeshLoadError(ValueError):
    """A mesh file could not be read: missing, unreadable, truncated or empty."""


class PrimitiveBounds:
    """Axis-aligned boxes of a scene's primitives: ``lo`` and ``hi``, each (n, 3), the box
    ``scene_lo``..``scene_hi`` around them all, and ``centroid`` (n, 3), computed on first use."""

    __slots__ = ("lo", "hi", "scene_lo", "scene_hi", "_centroid", "_compute_centroid")

    def __init__(self, lo: np.ndarray, hi: np.ndarray, scene_lo: np.ndarray, scene_hi: np.ndarray,
                 compute_centroid: Callable[[], np.ndarray]):
        self.lo, self.hi, self.scene_lo, self.scene_hi = lo, hi, scene_lo, scene_hi
        self._compute_centroid = compute_centroid
        self._centroid = None

    @property
    def centroid(self) -> np.ndarray:
        if self._centroid is None:
            self._centroid = self._compute_centroid()
        return self._centroid


class TriangleMesh:
    """An indexed triangle mesh.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Finite vertex positions.
    faces : (F, 3) array_like of int
        Vertex indices of each triangle, ``0 <= index < V``; at least one face.
        Degenerate (zero-area) triangles are allowed and are never hit.
    """

    kind = TRIANGLE

    def __init__(self, vertices, faces):
        self.vertices = as_points("vertices", vertices)
        self.faces = as_index_triples("faces", faces, len(self.vertices))

    @functools.cached_property
    def geometry(self) -> np.ndarray:
        """(F, 9) float64: each triangle's three vertices, gathered on first use (a structure
        that reorders them gathers its own copy instead)."""
        return np.ascontiguousarray(self.vertices[self.faces].reshape(-1, 9))

    @functools.cached_property
    def float32_exact(self) -> bool:
        """Whether every vertex coordinate is a float32 number (as read from binary PLY or STL)."""
        return float32_exact(self.vertices)

    def gather(self, order: np.ndarray, out=None, *, indexed: bool = False):
        """The faces ``order`` in that order, in the smallest exact layout of
        :mod:`rayaccel.geometry.gather`: float32 lanes, four triangles a group, when
        :attr:`float32_exact`, else vertex indices into the vertices renumbered by first use.
        Lanes go into ``out`` when it is lanes of that shape. ``indexed`` asks for the indexed
        layout on a float32 mesh too, for an ``order`` that repeats faces (a kd-tree's
        references), where lanes repeat them whole."""
        return gather_triangles(self.vertices, self.faces, np.ascontiguousarray(order, dtype=np.int64),
                                not indexed and self.float32_exact, out)

    def __len__(self) -> int:
        return len(self.faces)

    def __repr__(self) -> str:
        return f"TriangleMesh({len(self.vertices)} vertices, {len(self.faces)} triangles)"

    @property
    def prim_layout(self) -> tuple[np.ndarray, np.ndarray]:
        """``(faces, vertices)``: the triangles in the indexed layout of :mod:`rayaccel.geometry.gather`,
        over the mesh's own arrays, for kernels that read a few triangles each (no rows gathered)."""
        return self.faces, self.vertices

    def bounds(self) -> PrimitiveBounds:
        """The triangles' boxes, read through :attr:`prim_layout` (the rows of :attr:`geometry` are
        not gathered for them)."""
        return PrimitiveBounds(*primitive_bounds(TRIANGLE, self.prim_layout),
                               partial(triangle_centroids, self.prim_layout))

    def face_normals(self) -> np.ndarray:
        """Unit normals (F, 3) by the right-hand rule; zero for degenerate faces."""
        corners = self.geometry.reshape(-1, 3, 3)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)

    def vertex_normals(self) -> np.ndarray:
        """Area-weighted unit vertex normals (V, 3), for smooth shading."""
        corners = self.geometry.reshape(-1, 3, 3)
        weighted = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals = np.zeros_like(self.vertices)
        for corner in range(3):
            np.add.at(normals, self.faces[:, corner], weighted)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


class Spheres:
    """A set of spheres.

    Parameters
    ----------
    centers : (N, 3) array_like of float
    radii : (N,) array_like of float, or a scalar for all spheres; each > 0 and finite.
    """

    kind = SPHERE

    def __init__(self, centers, radii):
        self.centers = as_points("centers", centers)
        radii = np.asarray(radii, dtype=np.float64)
        if radii.ndim == 0:
            radii = np.full(len(self.centers), float(radii))
        if radii.shape != (len(self.centers),):
            raise ValueError(
                f"radii must be a scalar or have shape ({len(self.centers)},), got {radii.shape}"
            )
        if not np.isfinite(radii).all():
            raise ValueError("radii contain NaN or infinite values")
        if (radii <= 0).any():
            first = int(np.flatnonzero(radii <= 0)[0])
            raise ValueError(f"radii must be positive; radius {first} is {radii[first]}")
        self.radii = np.ascontiguousarray(radii)
        self.geometry = np.ascontiguousarray(np.column_stack([self.centers, self.radii]))

    @property
    def prim_layout(self) -> np.ndarray:
        """The spheres' rows, :attr:`geometry`: the layout kernels read, as a mesh's
        :attr:`TriangleMesh.prim_layout`."""
        return self.geometry

    def gather(self, order: np.ndarray, out: np.ndarray | None = None, *, indexed: bool = False) -> np.ndarray:
        """``geometry[order]``, written into ``out`` (len(order), 4) when given. Spheres have rows
        only: ``indexed``, which a mesh's :meth:`TriangleMesh.gather` takes, changes nothing."""
        return np.take(self.geometry, order, axis=0, out=out)

    def __len__(self) -> int:
        return len(self.centers)

    def __repr__(self) -> str:
        return f"Spheres({len(self.centers)})"

    def bounds(self) -> PrimitiveBounds:
        return PrimitiveBounds(*primitive_bounds(SPHERE, self.geometry), partial(sphere_centroids, self.geometry))


def random_spheres(n: int, seed: int = 0, fill: float = 0.05) -> Spheres:
    """The lecture's experiment: ``n`` random spheres inside the unit cube.

    All spheres share the radius ``r = (3 * fill / (4 * pi * n)) ** (1/3)``, so
    that their volumes add up to ``fill`` of the cube whatever ``n`` is: the
    scene's covered fraction, the expected free path of a ray in cell widths of
    a grid with 8n cells, and so the look of the images stay the same as ``n``
    grows. Centres are uniform in ``[r, 1 - r]^3``, so every sphere lies inside
    the cube; spheres may overlap.
    """
    n = as_positive_int("n", n)
    if not 0 < fill < 1:
        raise ValueError(f"fill must lie in (0, 1), got {fill}")
    radius = (3.0 * fill / (4.0 * np.pi * n)) ** (1.0 / 3.0)
    rng = np.random.default_rng(seed)
    centers = rng.uniform(radius, 1.0 - radius, size=(n, 3))
    return Spheres(centers, radius)


def _read_bytes(path: Path) -> tuple[bytes, str]:
    if not path.exists():
        raise MeshLoadError(f"mesh file not found: {path}")
    if not path.is_file():
        raise MeshLoadError(f"not a file: {path}")
    suffixes = [s.lower() for s in path.suffixes]
    compressed = bool(suffixes) and suffixes[-1] == ".gz"
    file_type = (suffixes[-2] if compressed and len(suffixes) > 1 else suffixes[-1] if suffixes else "")
    file_type = file_type.lstrip(".")
    if file_type not in {"obj", "ply", "stl", "off"}:
        raise MeshLoadError(f"unsupported mesh format {file_type!r} for {path} (use OBJ, PLY, STL or OFF)")
    try:
        data = path.read_bytes()
        if compressed:
            data = gzip.decompress(data)
    except (OSError, EOFError) as exc:
        raise MeshLoadError(f"cannot read {path}: {exc}") from None
    return data, file_type


def load_mesh(source) -> TriangleMesh:
    """Read a triangle mesh.

    Parameters
    ----------
    source : str, os.PathLike or trimesh.Trimesh
        An OBJ, PLY, STL or OFF file, optionally gzip-compressed (``.obj.gz``),
        or an already loaded ``trimesh.Trimesh``. Files with several objects are
        merged into one mesh. Vertices are kept as stored (no merging).

    Raises
    ------
    MeshLoadError
        The file is missing, unreadable, truncated, of an unknown format or holds no triangle.
    """
    import trimesh

    if isinstance(source, trimesh.Trimesh):
        return TriangleMesh(source.vertices, source.faces)
    if not isinstance(source, (str, os.PathLike)):
        raise TypeError(f"load_mesh expects a path or a trimesh.Trimesh, got {type(source).__name__}")
    path = Path(source)
    data, file_type = _read_bytes(path)
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=file_type, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types for corrupt input
        raise MeshLoadError(f"cannot parse {path} as {file_type.upper()}: {exc}") from None
    faces = getattr(loaded, "faces", None)
    if faces is None or len(faces) == 0:
        raise MeshLoadError(f"{path} holds no triangles")
    try:
        return TriangleMesh(loaded.vertices, loaded.faces)
    except (TypeError, ValueError) as exc:
        raise MeshLoadError(f"{path} is corrupt: {exc}") from None
