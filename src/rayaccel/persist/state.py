"""An accelerator as ``(state, arrays)`` and back: the part the file format and pickling share.

``state`` is JSON-ready: the method, its options, the build time, the scene's
kind and the structure's scalars (:mod:`.layouts`); for a two-level scene also
the instances and one nested state per object. ``arrays`` maps names to numpy
arrays. :func:`rebuild` trusts neither: every value is checked before a
structure is put together.
"""

from __future__ import annotations

import numpy as np

from ..instances import Scene, as_transform
from ..scene import Spheres, TriangleMesh
from ..structures.base import Accelerator
from ..structures.instanced.accelerator import InstancedScene
from ..structures.registry import build_class, methods
from . import checks as c
from .layouts import binary_tree, layout_of

__all__ = ["describe", "rebuild"]

_SCENE = "scene"


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _scene_arrays(scene, prefix):
    if isinstance(scene, TriangleMesh):
        return "mesh", {f"{prefix}scene.vertices": scene.vertices, f"{prefix}scene.faces": scene.faces}
    return "spheres", {f"{prefix}scene.centers": scene.centers, f"{prefix}scene.radii": scene.radii}


def describe(accel, prefix: str = "") -> tuple[dict, dict]:
    """``(state, arrays)`` of ``accel``, array names under ``prefix``."""
    if isinstance(accel, InstancedScene):
        return _describe_scene(accel, prefix)
    save, _ = layout_of(type(accel))
    kind, arrays = _scene_arrays(accel.scene, prefix)
    meta, own = save(accel)
    arrays.update({prefix + name: a for name, a in own.items()})
    state = {"method": accel.method, "options": _jsonable(accel.options), "build_seconds": accel.build_seconds,
             "scene": kind, "structure": _jsonable(meta)}
    return state, arrays


def _describe_scene(accel, prefix):
    box, first, count, order = accel.top
    arrays = {f"{prefix}instances.object": accel.instance_object, f"{prefix}instances.transform": accel.transforms,
              f"{prefix}top.node_box": box, f"{prefix}top.node_first": first, f"{prefix}top.node_count": count,
              f"{prefix}top.prim_order": order}
    objects = []
    for k, obj in enumerate(accel.objects):
        state, own = describe(obj, f"{prefix}object{k}.")
        objects.append(state)
        arrays.update(own)
    state = {"method": _SCENE, "object_method": accel.method, "options": _jsonable(accel.options),
             "build_seconds": accel.build_seconds, "objects": objects}
    if hasattr(accel, "top_sah_cost_at_build"):
        state["top_sah_cost_at_build"] = accel.top_sah_cost_at_build
    return state, arrays


def _scoped(arrays, prefix):
    return {name[len(prefix):]: a for name, a in arrays.items() if name.startswith(prefix)}


def _rebuild_scene_object(kind, arrays):
    try:
        if kind == "mesh":
            vertices = c.array(arrays, "scene.vertices", np.float64, (None, 3))
            faces = c.array(arrays, "scene.faces", np.int64, (None, 3))
            return TriangleMesh(vertices, faces)
        c.require(kind == "spheres", f"unknown scene kind {kind!r}")
        centers = c.array(arrays, "scene.centers", np.float64, (None, 3))
        radii = c.array(arrays, "scene.radii", np.float64, (len(centers),))
        return Spheres(centers, radii)
    except c.CorruptFileError:
        raise
    except (TypeError, ValueError) as exc:
        raise c.CorruptFileError(f"the saved scene is invalid: {exc}") from None


def rebuild(state: dict, arrays: dict, prefix: str = ""):
    """The accelerator ``describe`` took apart, after checking every value."""
    c.require(isinstance(state, dict), "a saved state is malformed")
    method = state.get("method")
    options = state.get("options")
    build_seconds = state.get("build_seconds")
    c.require(isinstance(options, dict), "the saved options are malformed")
    c.require(isinstance(build_seconds, (int, float)), "the saved build time is malformed")
    if method == _SCENE:
        return _rebuild_scene(state, arrays, prefix)
    c.require(method in methods(), f"unknown method {method!r}")
    scoped = _scoped(arrays, prefix)
    scene = _rebuild_scene_object(state.get("scene"), scoped)
    cls = build_class(method)
    accel = cls.__new__(cls)
    Accelerator.__init__(accel, scene, options)
    accel.build_seconds = float(build_seconds)
    meta = state.get("structure")
    c.require(isinstance(meta, dict), "the saved structure is malformed")
    _, load = layout_of(cls)
    load(accel, meta, scoped)
    return accel


def _rebuild_scene(state, arrays, prefix):
    objects_state = state.get("objects")
    c.require(isinstance(objects_state, list) and objects_state, "the saved scene has no objects")
    method = state.get("object_method")
    c.require(method in methods(), f"unknown method {method!r}")
    objects = [rebuild(s, arrays, f"{prefix}object{k}.") for k, s in enumerate(objects_state)]
    c.require(all(obj.method == method for obj in objects), "the scene's objects were built by other methods")
    scoped = _scoped(arrays, prefix)
    instance_object = c.array(scoped, "instances.object", np.int64, (None,))
    n = len(instance_object)
    c.require(n >= 1, "the saved scene has no instances")
    c.index_range("instances.object", instance_object, 0, len(objects))
    transforms = c.array(scoped, "instances.transform", np.float64, (n, 4, 4))
    scene = Scene()
    try:
        for o, matrix in zip(instance_object, transforms):
            scene.add(objects[o].scene, as_transform(matrix))
    except ValueError as exc:
        raise c.CorruptFileError(f"a saved instance transform is invalid: {exc}") from None
    box, first, count, order, depth = binary_tree(scoped, "top", "the top level", "top level", n)
    accel = InstancedScene.__new__(InstancedScene)
    Accelerator.__init__(accel, scene, state["options"])
    accel.method = method
    accel.objects = objects
    accel._place(instance_object, transforms)
    accel.top = (box, first, count, order)
    accel.top_depth = int(depth.max())
    accel.build_seconds = float(state["build_seconds"])
    if isinstance(state.get("top_sah_cost_at_build"), float):
        accel.top_sah_cost_at_build = state["top_sah_cost_at_build"]
    return accel
