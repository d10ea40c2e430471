"""``build()`` and ``methods()``: the one door to every acceleration structure."""

from __future__ import annotations

from .._memory import require_memory
from ..instances import Scene
from ..scene import Spheres, TriangleMesh
from .bvh.accelerator import BVH_CLASSES
from .grid.accelerator import UniformGrid
from .hgrid.accelerator import HierarchicalGrid
from .hybrid.accelerator import GridBvh
from .kdtree.accelerator import KdTree
from .none import BruteForce
from .octree.accelerator import Octree

__all__ = ["DEFAULT_METHOD", "build", "build_class", "methods"]

_METHODS = {
    "none": BruteForce,
    "grid": UniformGrid,
    "hgrid": HierarchicalGrid,
    "grid-bvh": GridBvh,
    **{cls.method: cls for cls in BVH_CLASSES},
    "kdtree": KdTree,
    "octree": Octree,
}

DEFAULT_METHOD = "bvh-binned"
"""The method :func:`build` and the command line take when none is named: the fastest to trace
(see the benchmark table in the README) and among the fastest to build."""


def methods() -> list[str]:
    """Every method name :func:`build` accepts."""
    return list(_METHODS)


def build(scene, method: str = DEFAULT_METHOD, **options):
    """Build acceleration structure ``method`` over ``scene``.

    Parameters
    ----------
    scene : TriangleMesh, Spheres, trimesh.Trimesh or Scene
        For a :class:`rayaccel.Scene`, every distinct object gets a structure of
        ``method`` with ``options``, under a top-level BVH over its instances
        (:mod:`rayaccel.structures.instanced`).
    method : str
        One of :func:`methods` (:data:`DEFAULT_METHOD` when not given); the options of each are
        documented on its class (``help(rayaccel.build_class(method))``).
    **options
        Keyword options of that method; unknown ones raise ``TypeError``.
    """
    if method not in _METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(_METHODS)}")
    cls = _METHODS[method]
    if isinstance(scene, Scene):
        from .instanced.accelerator import InstancedScene

        scene._require_instances()
        require_memory(f"building {method!r} over the scene's objects ({sum(map(len, scene.objects)):,} primitives)",
                       cls.build_bytes_per_primitive * sum(map(len, scene.objects)))
        return InstancedScene(scene, method, [cls(obj, **options) for obj in scene.objects], options)
    if not isinstance(scene, (TriangleMesh, Spheres)):
        try:
            import trimesh
        except ImportError:  # pragma: no cover - trimesh is a dependency
            trimesh = None
        if trimesh is not None and isinstance(scene, trimesh.Trimesh):
            scene = TriangleMesh(scene.vertices, scene.faces)
        else:
            raise TypeError("scene must be a TriangleMesh, Spheres, trimesh.Trimesh or Scene, "
                            f"got {type(scene).__name__}")
    require_memory(f"building {method!r} over {len(scene):,} primitives", cls.build_bytes_per_primitive * len(scene))
    return cls(scene, **options)


def build_class(method: str):
    """The class behind ``method``, whose docstring lists its options."""
    if method not in _METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(_METHODS)}")
    return _METHODS[method]
