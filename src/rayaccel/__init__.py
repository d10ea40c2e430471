"""rayaccel: ray-tracing acceleration structures from the textbooks, behind one fast query API.

>>> import rayaccel as ra
>>> mesh = ra.load_scene("bunny")
>>> accel = ra.build(mesh, "grid")
>>> hits = accel.intersect(origins, directions)
"""

from .catalog import builtin_scenes, load_scene
from .instances import Scene
from .persist import CorruptFileError, load_accelerator
from .rays import AllHits, Camera, Hits, RayCounters
from .scene import MeshLoadError, Spheres, TriangleMesh, load_mesh, random_spheres
from .structures.registry import build, build_class, methods

__all__ = [
    "AllHits",
    "Camera",
    "Hits",
    "RayCounters",
    "Scene",
    "CorruptFileError",
    "load_accelerator",
    "MeshLoadError",
    "Spheres",
    "TriangleMesh",
    "builtin_scenes",
    "load_mesh",
    "load_scene",
    "random_spheres",
    "build",
    "build_class",
    "methods",
]

__version__ = "0.1.0"
