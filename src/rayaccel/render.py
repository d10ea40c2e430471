"""A small renderer on top of the query API: primary rays, point lights with
shadow rays, Lambert shading, PNG output, and per-pixel cost heatmaps.

Rendering runs in bands of rows so that a progress callback can report on
large images; every band is one batch query, so all the speed is the
acceleration structure's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .catalog import load_scene
from .instances import Scene
from .rays import Camera
from .scene import SPHERE, TRIANGLE
from .structures.base import Accelerator

__all__ = ["RenderResult", "PixelResult", "default_camera", "default_lights", "render", "render_pixels", "assemble",
           "save_png", "save_heatmap", "warm_up"]

_BAND_ROWS = 64
_BACKGROUND_TOP = np.array([0.10, 0.12, 0.16])
_BACKGROUND_BOTTOM = np.array([0.02, 0.02, 0.03])
_AMBIENT = 0.08


@dataclass
class RenderResult:
    """A rendered image (height, width, 3) in linear RGB [0, 1], with the work it took."""

    image: np.ndarray
    nodes: np.ndarray            # (height, width) nodes or cells visited by the primary ray
    tests: np.ndarray            # (height, width) primitive tests of the primary ray
    primary_seconds: float = 0.0
    shadow_seconds: float = 0.0
    primary_rays: int = 0
    shadow_rays: int = 0

    @property
    def trace_seconds(self) -> float:
        return self.primary_seconds + self.shadow_seconds

    @property
    def mrays_per_second(self) -> float:
        """Primary closest-hit rays per second, in millions."""
        return self.primary_rays / max(self.primary_seconds, 1e-12) / 1e6


def _scene_box(scene_or_structure) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(scene_or_structure, Accelerator):
        return scene_or_structure.scene_box
    bounds = scene_or_structure.bounds()
    return bounds.scene_lo, bounds.scene_hi


def default_camera(scene) -> Camera:
    """A camera that frames the whole scene (or a built structure's scene), looking slightly
    down from the front right."""
    return Camera.framing(*_scene_box(scene))


def default_lights(scene, camera: Camera | None = None) -> np.ndarray:
    """One point light above and to the left of the camera, outside the scene (or a built
    structure's scene)."""
    lo, hi = _scene_box(scene)
    camera = camera or default_camera(scene)
    center = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    offset = camera.eye - center
    offset /= np.linalg.norm(offset)
    direction = offset + 0.9 * camera.true_up - 0.6 * camera.right
    return (center + 2.5 * radius * direction / np.linalg.norm(direction))[None, :]


def _albedo(scene, prim: np.ndarray) -> np.ndarray:
    if scene.kind == SPHERE:
        hue = (prim * 0.61803398875) % 1.0
        return 0.35 + 0.5 * np.stack(
            [0.5 + 0.5 * np.cos(2 * np.pi * (hue + s)) for s in (0.0, 0.33, 0.67)], axis=1
        )
    return np.broadcast_to(np.array([0.82, 0.78, 0.72]), (len(prim), 3))


def _normals(scene, hits_prim, u, v, points, vertex_normals):
    if scene.kind == SPHERE:
        return (points - scene.centers[hits_prim]) / scene.radii[hits_prim, None]
    corners = scene.faces[hits_prim]
    n = ((1 - u - v)[:, None] * vertex_normals[corners[:, 0]] + u[:, None] * vertex_normals[corners[:, 1]]
         + v[:, None] * vertex_normals[corners[:, 2]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    flat = scene.face_normals()[hits_prim]
    return np.where(length > 1e-12, n / np.maximum(length, 1e-300), flat)


def _instance_surface(accel, geom, prim, u, v, points, vertex_normals):
    """Normals and albedo of hits on a two-level scene: each object's own, computed in its
    frame and turned into the world by the inverse transpose of its instance's transform."""
    scene = accel.scene
    normal = np.empty_like(points)
    albedo = np.empty_like(points)
    obj_of_hit = accel.instance_object[geom]
    for o in np.unique(obj_of_hit):
        chosen = obj_of_hit == o
        obj = scene.objects[o]
        inverse = accel.inverse[geom[chosen]]
        local = np.einsum("kij,kj->ki", inverse[:, :3, :3], points[chosen]) + inverse[:, :3, 3]
        if o not in vertex_normals:
            vertex_normals[o] = obj.vertex_normals() if obj.kind != SPHERE else None
        local_normal = _normals(obj, prim[chosen], u[chosen], v[chosen], local, vertex_normals[o])
        world = np.einsum("kji,kj->ki", inverse[:, :3, :3], local_normal)
        normal[chosen] = world / np.maximum(np.linalg.norm(world, axis=1, keepdims=True), 1e-300)
        albedo[chosen] = _albedo(obj, prim[chosen])
    return normal, albedo


@dataclass
class PixelResult:
    """Some pixels of a frame, in the order asked for: ``color`` (m, 3) linear RGB, ``nodes`` and
    ``tests`` (m,) the primary ray's work, and the time and rays the queries took."""

    color: np.ndarray
    nodes: np.ndarray
    tests: np.ndarray
    primary_seconds: float = 0.0
    shadow_seconds: float = 0.0
    primary_rays: int = 0
    shadow_rays: int = 0


def render_pixels(accel, camera: Camera, width: int, height: int, lights, shadows: bool = True, pixels=None,
                  progress=None) -> PixelResult:
    """Shade the flat pixel indices ``pixels`` (row-major; all when None) of a ``width`` x ``height``
    frame, in bands of ``_BAND_ROWS`` rows' worth of pixels, one batch query per band.

    A pixel's colour depends on that pixel alone, so any split of a frame into pieces of whole bands
    (as :func:`rayaccel.distributed.render` makes) gives the same batches as :func:`render`, and the
    same bits. ``progress(done_pixels, total_pixels)`` after each band.
    """
    scene = accel.scene
    lights = np.atleast_2d(np.asarray(lights, float))
    instanced = isinstance(scene, Scene)
    vertex_normals = {} if instanced else scene.vertex_normals() if scene.kind != SPHERE else None
    scene_lo, scene_hi = accel.scene_box
    epsilon = 1e-6 * float(np.linalg.norm(scene_hi - scene_lo))
    rendered = np.arange(height * width) if pixels is None else np.asarray(pixels, dtype=np.int64).ravel()
    if len(rendered) and (rendered.min() < 0 or rendered.max() >= height * width):
        raise ValueError(f"pixels must be flat indices in [0, {height * width}) for a {width}x{height} image")
    result = PixelResult(np.zeros((len(rendered), 3)), np.zeros(len(rendered), dtype=np.int64),
                         np.zeros(len(rendered), dtype=np.int64))
    band = _BAND_ROWS * width
    for first in range(0, len(rendered), band):
        band_pixels = rendered[first:first + band]
        rows = slice(first, first + len(band_pixels))
        origins, directions = camera.rays(width, height, band_pixels)
        start = time.perf_counter()
        hits = accel.intersect(origins, directions, counters=True)
        result.primary_seconds += time.perf_counter() - start
        result.primary_rays += len(band_pixels)
        result.nodes[rows] = hits.counters.nodes
        result.tests[rows] = hits.counters.tests
        sky = (band_pixels // width / max(height - 1, 1))[:, None]
        color = (1 - sky) * _BACKGROUND_TOP + sky * _BACKGROUND_BOTTOM
        h = hits.hit
        if h.any():
            prim = hits.prim[h]
            points = origins[h] + hits.t[h, None] * directions[h]
            if instanced:
                normal, albedo = _instance_surface(accel, hits.geom[h], prim, hits.u[h], hits.v[h], points,
                                                   vertex_normals)
            else:
                normal = _normals(scene, prim, hits.u[h], hits.v[h], points, vertex_normals)
                albedo = _albedo(scene, prim)
            facing = np.einsum("ij,ij->i", normal, directions[h]) > 0
            normal[facing] *= -1
            lit_color = _AMBIENT * albedo
            shifted = points + epsilon * normal
            for light in lights:
                to_light = light - shifted
                lambert = np.clip(np.einsum("ij,ij->i", normal, to_light) / np.linalg.norm(to_light, axis=1), 0, None)
                lit = lambert > 0
                if shadows and lit.any():
                    start = time.perf_counter()
                    blocked = accel.occluded(shifted[lit], to_light[lit], 0.0, 1.0)
                    result.shadow_seconds += time.perf_counter() - start
                    result.shadow_rays += int(lit.sum())
                    lambert[np.flatnonzero(lit)[blocked]] = 0.0
                lit_color = lit_color + albedo * lambert[:, None] * (0.92 / len(lights))
            color[h] = lit_color
        result.color[rows] = color
        if progress is not None:
            progress(rows.stop, len(rendered))
    return result


def render(accel, camera: Camera | None = None, width: int = 512, height: int = 512, lights=None,
           shadows: bool = True, progress=None, pixels=None) -> RenderResult:
    """Render ``accel.scene`` through ``camera`` with Lambert shading and hard shadows.

    Parameters
    ----------
    accel : Accelerator
        Any built structure, over a mesh, spheres or a :class:`rayaccel.Scene`; its queries
        do all ray casting.
    camera : Camera, optional
        :func:`default_camera` when None.
    lights : (k, 3) array_like, optional
        Point light positions; :func:`default_lights` when None.
    shadows : bool
        Cast one shadow ray per hit and light.
    progress : callable(done_rows, total_rows), optional
    pixels : array_like of int, optional
        Render only these flat pixel indices (row-major), leaving the others black with no
        work counted: a sample of a frame too slow to render whole. All pixels when None.
    """
    camera = camera or default_camera(accel)
    lights = default_lights(accel, camera) if lights is None else lights
    rendered = np.arange(height * width) if pixels is None else np.asarray(pixels, dtype=np.int64).ravel()
    report = None if progress is None else lambda done, total: progress(round(height * done / max(total, 1)), height)
    shaded = render_pixels(accel, camera, width, height, lights, shadows, rendered, report)
    return assemble(shaded, rendered, width, height)


def assemble(shaded: PixelResult, pixels: np.ndarray, width: int, height: int,
             result: RenderResult | None = None) -> RenderResult:
    """Write the pixels ``shaded`` (flat indices ``pixels``) into ``result``, a black frame with no work
    counted when None, adding their ray counts and times; returns ``result``."""
    if result is None:
        result = RenderResult(np.zeros((height, width, 3)), np.zeros((height, width), dtype=np.int64),
                              np.zeros((height, width), dtype=np.int64))
    result.image.reshape(-1, 3)[pixels] = shaded.color
    result.nodes.reshape(-1)[pixels] = shaded.nodes
    result.tests.reshape(-1)[pixels] = shaded.tests
    result.primary_seconds += shaded.primary_seconds
    result.shadow_seconds += shaded.shadow_seconds
    result.primary_rays += shaded.primary_rays
    result.shadow_rays += shaded.shadow_rays
    return result


_WARM_UP_SCENES = {TRIANGLE: ("dragon-11k", "spot"), SPHERE: ("spheres:5000",)}
"""The small scenes :func:`warm_up` builds and renders: for triangles a mesh whose vertices are
float32 numbers and one whose are not, the two layouts of :mod:`rayaccel.geometry.gather` that
the leaves' primitives take (the kernels reading them compile once for each)."""

_WARM_UP_SIDE = 128
"""Side of :func:`warm_up`'s renders: each of these scenes then casts camera and shadow batches of
more than :data:`rayaccel.ray_order.MIN_PACKET_RAYS` rays (its two bands' shadow batches 1,244 and
1,789 rays on the dragon, 878 and 1,354 on spot, 2,003 and 2,201 on the spheres), so that the
packet walks compile too. At 8 x 8, on the dragon alone, the demo on an
empty cache compiled kernels while timed (grid-bvh 0.0065 Mrays/s on the bunny, whose vertices
are float64; the agglomerative BVH's shadow rays 0.0036)."""


def warm_up(methods, kinds=(TRIANGLE, SPHERE), progress=None) -> None:
    """Compile (or load from Numba's cache) every kernel that building and rendering with these
    methods uses for these primitive kinds, on small scenes (large enough for the kd-tree's
    binned top levels, in both triangle layouts, with batches large enough for packets), so that
    nothing timed afterwards compiles; ``progress(done, total)`` after each method."""
    from .structures.registry import build

    scenes = [load_scene(name) for kind in kinds for name in _WARM_UP_SCENES[kind]]
    for done, method in enumerate(methods, 1):
        # brute force walks no packets, and tests every primitive for every ray
        side = 8 if method == "none" else _WARM_UP_SIDE
        for scene in scenes:
            render(build(scene, method), width=side, height=side)
        if progress is not None:
            progress(done, len(methods))


def save_png(image: np.ndarray, path) -> Path:
    """Write a linear-RGB image as an sRGB-ish (gamma 2.2) 8-bit PNG."""
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    encoded = (np.clip(image, 0.0, 1.0) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    Image.fromarray(encoded).save(path)
    return path


def save_heatmap(values: np.ndarray, path, label: str, title: str = "") -> Path:
    """Write a per-pixel cost picture with a low-high colour scale (matplotlib); the scale ends at
    the 99.5th percentile so that a few extreme pixels do not wash out the rest."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    height, width = values.shape
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * height / width + 0.3), dpi=max(100, width // 6))
    top = max(float(np.percentile(values, 99.5)), 1.0)
    shown = ax.imshow(values, cmap="inferno", interpolation="nearest", vmin=0, vmax=top)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=9)
    bar = fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.02)
    bar.set_label(f"{label} per pixel, low - high (max {int(values.max())})")
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
