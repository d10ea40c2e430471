"""Scenes by name: the meshes rayaccel ships, its procedural scenes, and ``spheres:N``.

The dependency runs one way: :mod:`rayaccel.scene` (primitives, mesh loading) and
:mod:`rayaccel.procedural` (generated scenes) know nothing of the names listed here.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .procedural import PROCEDURAL_SCENES
from .scene import MeshLoadError, load_mesh, random_spheres

__all__ = ["data_directory", "builtin_scenes", "load_scene"]


def data_directory() -> Path:
    """The folder of the meshes rayaccel ships inside the package, with their credits in
    ``SOURCES.md`` (``$RAYACCEL_DATA`` overrides it)."""
    override = os.environ.get("RAYACCEL_DATA")
    folder = Path(override) if override else Path(__file__).resolve().parent / "data" / "meshes"
    if not folder.is_dir():
        raise MeshLoadError(f"the shipped meshes were not found in {folder}; reinstall rayaccel, or set RAYACCEL_DATA "
                            "to a folder holding them")
    return folder


_BUILTIN_MESHES = {
    "bunny": "stanford-bunny.obj",
    "dragon": "dragon_vrip.ply.gz",
    "dragon-203k": "dragon_vrip_res2.ply.gz",
    "dragon-48k": "dragon_vrip_res3.ply.gz",
    "dragon-11k": "dragon_vrip_res4.ply.gz",
    "armadillo": "armadillo.obj.gz",
    "buddha": "happy.obj.gz",
    "teapot": "teapot.obj",
    "spot": "spot.obj",
    "cornell-box": "cornell_box.obj",
    "sphere": "unit_sphere.STL",
}


def builtin_scenes() -> list[str]:
    """Names :func:`load_scene` knows besides file paths (``spheres:N`` takes any N)."""
    return sorted(_BUILTIN_MESHES) + sorted(PROCEDURAL_SCENES) + ["spheres:N"]


def load_scene(spec: str):
    """A scene from a name: a built-in mesh, a procedural scene (:mod:`rayaccel.procedural`),
    ``spheres:N[:seed]`` or a mesh file path."""
    match = re.fullmatch(r"spheres:([0-9_,]+)(?::([0-9]+))?", spec)
    if match:
        n = int(match.group(1).replace("_", "").replace(",", ""))
        return random_spheres(n, seed=int(match.group(2) or 0))
    if spec in _BUILTIN_MESHES:
        return load_mesh(data_directory() / _BUILTIN_MESHES[spec])
    if spec in PROCEDURAL_SCENES:
        return PROCEDURAL_SCENES[spec]()
    if Path(spec).suffix or Path(spec).exists():
        return load_mesh(spec)
    raise ValueError(f"unknown scene {spec!r}: give a mesh file or one of {', '.join(builtin_scenes())}")
