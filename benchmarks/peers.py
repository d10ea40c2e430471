"""The subjects of ``bench_structures.py``: rayaccel and each peer behind one query interface.

Every subject builds its structure from a ``TriangleMesh`` (timed), converts a
:class:`RaySet` into its own input format once (untimed), and answers closest-hit
and any-hit queries with NumPy arrays (timed). See ``bench_structures.py`` for how
the peers' ray intervals are matched.
"""

from __future__ import annotations

import copy
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from _common import SETTLE_SECONDS

import rayaccel as ra

BUILD_REPEATS = 5
"""Builds timed per subject; the build figure is their median. Three left one spike in a run free to
decide it: the full dragon's default BVH, unchanged, came out at 0.557, 0.616 and 0.712 s against
Embree's 0.605-0.626 in three runs of one evening; five rounds of the four builds in a process of
their own, three times, 0.479-0.513 s against 0.572-0.584 (2026-12-06)."""
CORES = os.cpu_count() or 1


@dataclass(frozen=True)
class RaySet:
    """Rays ``origins + t * directions`` (float64), searched over ``[t_min, t_max]``."""

    origins: np.ndarray
    directions: np.ndarray
    t_min: float = 0.0
    t_max: float = np.inf

    def __len__(self) -> int:
        return len(self.directions)

    def one_origin(self) -> np.ndarray | None:
        """The (1, 3) origin every ray starts from when they share one, as a camera's rays do, else
        None: a subject whose API takes one origin for all rays is given it so, as its users would
        pass it (rayaccel, Mitsuba 3); Embree's and Open3D's take an origin per ray."""
        shared = len(self.origins) and np.all(self.origins == self.origins[0])
        return self.origins[:1] if shared else None

    def without_t_min(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``(origins, directions, t_max)`` of the same segments starting at t = 0, for an API
        with no t_min: origins moved to ``t_min`` and t_max measured from there."""
        return self.origins + self.t_min * self.directions, self.directions, self.t_max - self.t_min


def interleaved_build_seconds(makes: list, repeats: int = BUILD_REPEATS) -> list[float]:
    """The median seconds of each of ``makes`` over ``repeats`` rounds in which they take turns, so
    that every build meets the same phases of a noisy machine. Timed one after another instead,
    the full dragon's Embree build came out at 0.549 s in one run and 0.768 s in another, ours at
    0.574-0.648 s; nine interleaved rounds in a process of their own gave 0.485 s against Embree's
    0.555 s. Each build follows the pause of :data:`_common.SETTLE_SECONDS`, as the timed queries do."""
    seconds = [[] for _ in makes]
    for _ in range(repeats):
        for k, make in enumerate(makes):
            time.sleep(SETTLE_SECONDS)
            start = time.perf_counter()
            make()
            seconds[k].append(time.perf_counter() - start)
    return [float(np.median(times)) for times in seconds]


class Subject:
    """One row: answers closest-hit and any-hit queries on a :class:`RaySet`.

    ``prepare`` converts a ray set into the subject's own input (not timed);
    ``closest`` returns the primitive hit by each ray (-1 for none) and ``any_hit`` a bool
    per ray, both as NumPy arrays, so that a timed call has done all of its work.
    Subjects sharing a ``group`` are variants of one peer: the table keeps the fastest
    per column and names it.
    """

    label = "?"
    short = "?"  # for narrow cells
    is_peer = True
    is_baseline = False  # the peer every row is also compared with: Embree on all cores
    group: str | None = None
    make = None  # builds the subject's structure again, for interleaved_build_seconds
    build_seconds = 0.0

    def variant(self, label: str, short: str | None = None, **changes) -> Subject:
        """A copy with other settings, sharing the built structure."""
        other = copy.copy(self)
        vars(other).update(changes, label=label, short=short or label)
        return other

    def prepare(self, rays: RaySet):
        raise NotImplementedError

    def closest(self, prepared) -> np.ndarray:
        raise NotImplementedError

    def any_hit(self, prepared) -> np.ndarray:
        raise NotImplementedError


class RayaccelSubject(Subject):
    """A rayaccel structure; ``reorder=False`` traces the rays in the order given, ``float32=True``
    gives it the rays rounded to float32, as every peer gets them (rayaccel's walks read float32
    rays as they are; ``t_min`` stays rayaccel's own). Rays from one origin get that origin once
    (:meth:`RaySet.one_origin`)."""

    is_peer = False

    def __init__(self, scene, method: str, reorder: bool = True, float32: bool = False):
        self.make = lambda: ra.build(scene, method)
        self.accel = self.make()
        self.reorder = reorder
        self.float32 = float32
        self.label = self.short = f"rayaccel {method}"

    def prepare(self, rays: RaySet) -> RaySet:
        one = rays.one_origin()
        origins = rays.origins if one is None else one
        dtype = np.float32 if self.float32 else np.float64
        return RaySet(origins.astype(dtype), rays.directions.astype(dtype), rays.t_min, rays.t_max)

    def closest(self, rays: RaySet) -> np.ndarray:
        return self.accel.intersect(rays.origins, rays.directions, rays.t_min, rays.t_max, reorder=self.reorder).prim

    def any_hit(self, rays: RaySet) -> np.ndarray:
        return self.accel.occluded(rays.origins, rays.directions, rays.t_min, rays.t_max, reorder=self.reorder)


class EmbreePeer(Subject):
    """Embree 4 through embreex (float32); with ``threads > 1`` the rays are split into that many
    parts traced on Python threads, as ``run`` releases the GIL."""

    def __init__(self, mesh, threads: int = 1):
        self.make = lambda: self._build(mesh)
        self.scene = self.make()
        self.threads, self.is_baseline = threads, threads == CORES
        self.label, self.short = self._label(threads), f"Embree {threads}T"

    @staticmethod
    def _label(threads: int) -> str:
        return f"Embree (embreex), {threads} thread{'s' * (threads > 1)}"

    def with_threads(self, threads: int) -> EmbreePeer:
        """The same BVH, queried on ``threads`` threads."""
        return self.variant(self._label(threads), f"Embree {threads}T", threads=threads,
                            is_baseline=threads == CORES)

    @staticmethod
    def _build(mesh):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene, mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32))
        scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # commits: builds the BVH
        return scene

    def prepare(self, rays: RaySet) -> list[tuple]:
        origins, directions, t_max = rays.without_t_min()
        dists = np.full(len(rays), t_max, np.float32) if np.isfinite(t_max) else None
        parts = np.array_split(np.arange(len(rays)), self.threads)
        return [(origins[p].astype(np.float32), directions[p].astype(np.float32),
                 None if dists is None else dists[p]) for p in parts]

    def _run(self, parts: list[tuple], query: str) -> np.ndarray:
        def run(part):
            origins, directions, dists = part
            return self.scene.run(origins, directions, dists=dists, query=query)

        if len(parts) == 1:
            return run(parts[0])
        with ThreadPoolExecutor(len(parts)) as pool:
            return np.concatenate(list(pool.map(run, parts)))

    def closest(self, parts) -> np.ndarray:
        return self._run(parts, "INTERSECT")

    def any_hit(self, parts) -> np.ndarray:
        return self._run(parts, "OCCLUDED") == 0  # embreex: 0 where occluded, -1 elsewhere


class Open3dPeer(Subject):
    """Open3D's RaycastingScene on all cores; its BVH is built on the first query, so the build
    time includes one query of one ray."""

    def __init__(self, mesh):
        import open3d

        self.o3d = open3d
        self.make = lambda: self._build(mesh)
        self.scene = self.make()
        self.label = f"Open3D RaycastingScene, {CORES} threads"
        self.short = "Open3D"

    def _build(self, mesh):
        scene = self.o3d.t.geometry.RaycastingScene()
        scene.add_triangles(self.o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                            self.o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        scene.cast_rays(self.o3d.core.Tensor(np.array([[0, 0, 0, 1, 1, 1]], np.float32)))
        return scene

    def prepare(self, rays: RaySet):
        origins, directions, t_max = rays.without_t_min()
        return self.o3d.core.Tensor(np.hstack([origins, directions]).astype(np.float32)), t_max

    def closest(self, prepared) -> np.ndarray:
        rays, t_max = prepared
        answer = self.scene.cast_rays(rays, nthreads=CORES)
        prim = answer["primitive_ids"].numpy().view(np.int32)  # INVALID_ID (2**32 - 1) reads as -1
        if np.isfinite(t_max):
            prim = np.where(answer["t_hit"].numpy() <= t_max, prim, -1)
        return prim

    def any_hit(self, prepared) -> np.ndarray:
        rays, t_max = prepared
        return self.scene.test_occlusions(rays, tfar=t_max, nthreads=CORES).numpy()


class MitsubaPeer(Subject):
    """Mitsuba 3 (variant llvm_ad_rgb, Embree inside) on a mesh made in memory; the build is the
    mesh and scene creation, which builds the BVH. ``coherent`` is the hint passed to every query."""

    def __init__(self, mesh, coherent: bool = False):
        import drjit
        import mitsuba

        mitsuba.set_variant("llvm_ad_rgb")
        self.mi, self.dr = mitsuba, drjit
        self.make = lambda: self._build(mesh)
        self.scene = self.make()
        self.coherent = coherent
        self.group = f"Mitsuba 3 llvm_ad_rgb, {drjit.thread_count()} threads"
        self.short = "Mitsuba 3"
        self.label = self._label(coherent)

    def _label(self, coherent: bool) -> str:
        return f"{self.group}, coherent={coherent}"

    def with_coherent(self, coherent: bool) -> MitsubaPeer:
        """The same scene, queried with another ``coherent`` hint."""
        return self.variant(self._label(coherent), self.short, coherent=coherent)

    def _build(self, mesh):
        mi = self.mi
        shape = mi.Mesh("mesh", len(mesh.vertices), len(mesh.faces))
        params = mi.traverse(shape)
        params["vertex_positions"] = mi.Float(mesh.vertices.astype(np.float32).ravel())
        params["faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
        params.update()
        return mi.load_dict({"type": "scene", "mesh": shape})

    def prepare(self, rays: RaySet):
        mi, dr = self.mi, self.dr
        origins, directions, t_max = rays.without_t_min()

        def columns(array):
            return [mi.Float(np.ascontiguousarray(array[:, k], np.float32)) for k in range(3)]

        one = rays.one_origin() if rays.t_min == 0.0 else None
        origin = mi.Point3f(*columns(origins)) if one is None else mi.Point3f(*one[0].astype(np.float32).tolist())
        ray = mi.Ray3f(origin, mi.Vector3f(*columns(directions)))
        if np.isfinite(t_max):
            ray.maxt = dr.full(mi.Float, t_max, len(rays))
        dr.eval(ray)
        dr.sync_thread()
        return ray

    def closest(self, ray) -> np.ndarray:
        mi, dr = self.mi, self.dr
        hit = self.scene.ray_intersect_preliminary(ray, coherent=self.coherent)
        prim = dr.select(hit.is_valid(), mi.Int32(hit.prim_index), -1)
        dr.eval(prim)
        dr.sync_thread()
        return prim.numpy()

    def any_hit(self, ray) -> np.ndarray:
        occluded = self.scene.ray_test(ray, coherent=self.coherent)
        self.dr.eval(occluded)
        self.dr.sync_thread()
        return occluded.numpy()
