"""Ray batches, query results and the pinhole camera."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._jit import inline_kernel, unsigned
from ._ray_lanes import origin_at
from ._validate import as_per_ray, as_points, check_ray_arrays

__all__ = ["RayBatch", "RayCounters", "WORK_COLUMNS", "Hits", "AllHits", "Camera", "prepare_rays", "random_lines",
           "origin_at", "ray_at", "ray_limit", "result_row"]


class RayBatch(NamedTuple):
    """Validated rays: float64 (or, for walks that take them, float32) C-contiguous
    ``origins``/``directions`` (n, 3), ``t_min``/``t_max`` (n,),
    and ``hit_slot`` (n,) int64, the row of the output arrays that takes each ray's hit:
    ``arange(n)`` as given, a permutation once :func:`rayaccel.ray_order.coherent_batch`
    has sorted the rays.

    A *compact* batch (:func:`prepare_rays` with ``compact=True``) leaves out what every ray
    shares: ``t_min`` or ``t_max`` of shape (1,) holds for all rays, and an empty ``hit_slot``
    means rays in the order given. Kernels read both through :func:`ray_limit` and
    :func:`result_row`, so they take either form; code that slices or indexes a batch's arrays
    takes a full one. Writing the three arrays for a million rays cost about 3 ms of a
    camera-ray query's 44 ms on the forest scene (two threads), with nothing to compute.
    Likewise ``origins`` of shape (3,) is one origin every ray starts from, as a pinhole
    camera's rays do (:func:`prepare_rays` with ``shared_origin``): read through
    :func:`origin_at` and :func:`ray_at`, or :meth:`with_origin_per_ray` for other code.
    """

    origins: np.ndarray
    directions: np.ndarray
    t_min: np.ndarray
    t_max: np.ndarray
    hit_slot: np.ndarray

    @property
    def size(self) -> int:
        """How many rays the batch holds."""
        return len(self.directions)

    @property
    def shares_origin(self) -> bool:
        """Whether ``origins`` is one (3,) origin of every ray (:func:`prepare_rays` with ``shared_origin``)."""
        return self.origins.ndim == 1

    def with_origin_per_ray(self) -> RayBatch:
        """The batch with an origin row per ray, for code that takes an (n, 3) ``origins`` only."""
        return self._replace(origins=_per_ray(self.origins, self.directions)) if self.shares_origin else self


class RayCounters(NamedTuple):
    """Per-ray work of one query, each (n,) int64.

    ``nodes``: nodes or cells visited, leaves included; ``tests``: primitive
    intersection tests run; ``mailbox_skips``: tests skipped because the primitive
    was already tested for this ray (structures that reference a primitive from
    several cells, with mailboxing; zero elsewhere); ``leaves``: the leaves among
    the nodes (a grid's cells are all leaves, a hierarchical grid's those without a
    grid of their own), so that ``nodes - leaves`` are the interior traversal steps.
    """

    nodes: np.ndarray
    tests: np.ndarray
    mailbox_skips: np.ndarray
    leaves: np.ndarray


WORK_COLUMNS = len(RayCounters._fields)
"""Columns of the (n, WORK_COLUMNS) int64 array the kernels write counters into, in
:class:`RayCounters` order."""


class Hits(NamedTuple):
    """Closest hits of a ray batch.

    ``t`` (n,) float64: distance in units of the given direction, ``inf`` on a miss;
    ``prim`` (n,) int64: index of the primitive hit, -1 on a miss;
    ``u``, ``v`` (n,) float64: for triangles the barycentrics of the hit point
    ``(1 - u - v) * v0 + u * v1 + v * v2``; for spheres the texture coordinates
    ``u = azimuth / 2pi`` in [0, 1) and ``v = polar angle / pi`` in [0, 1]; NaN on a miss;
    ``counters``: :class:`RayCounters` when asked for, else None;
    ``geom`` (n,) int64: which object of a :class:`rayaccel.Scene` was hit (the id
    ``scene.add`` returned), 0 on any hit of a plain mesh or sphere set, -1 on a miss.
    """

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    counters: RayCounters | None = None
    geom: np.ndarray | None = None

    @property
    def hit(self) -> np.ndarray:
        """(n,) bool, True where the ray hit something."""
        return self.prim >= 0


class AllHits(NamedTuple):
    """Every hit of each ray of a batch (:meth:`rayaccel.structures.base.Accelerator.intersect_all`).

    ``offsets`` (n + 1,) int64: ray ``i``'s hits are the entries ``offsets[i]:offsets[i + 1]``
    of the flat arrays, sorted by ``t``, equal distances by ``prim`` (by ``geom``, then ``prim``
    in a scene of instances); ``t``, ``prim``, ``u``, ``v``, ``geom`` as in :class:`Hits`, one
    entry per hit (``geom`` is 0 for a plain mesh or sphere set).
    """

    offsets: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    geom: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        """(n,) int64: hits per ray."""
        return np.diff(self.offsets)

    @property
    def ray(self) -> np.ndarray:
        """(m,) int64: the ray each hit belongs to."""
        return np.repeat(np.arange(len(self.offsets) - 1), np.diff(self.offsets))


def _per_ray(origins, directions):
    """One origin (a row or a (3,) array) copied to a C-contiguous row per ray of ``directions``:
    written once, then the rows written so far copied after themselves until every row is,
    each copy one block of memory. ``np.ascontiguousarray`` of the origin broadcast to every
    ray, which copies three numbers at a time, took 5.1 ms for 2^20 float64 rays from a (1, 3)
    origin and 9.3 ms from a (3,) one; this, 0.9 ms (means of 20 calls)."""
    rows = np.empty(directions.shape, dtype=origins.dtype)
    if len(rows):
        rows[0] = origins.reshape(3)
        filled = 1
        while filled < len(rows):
            step = min(filled, len(rows) - filled)
            rows[filled:filled + step] = rows[:step]
            filled += step
    return rows


def _one_row_if_repeated(origins):
    """``origins``' first row alone when it is an array whose rows all alias it (stride 0, as
    ``np.broadcast_to(eye, shape)`` makes), so that one origin is not copied once per ray."""
    if isinstance(origins, np.ndarray) and origins.ndim == 2 and len(origins) > 1 and origins.strides[0] == 0:
        return origins[:1]
    return origins


_IN_ORDER = np.empty(0, dtype=np.int64)
"""The ``hit_slot`` of a compact batch whose rays stay in the order given: empty, so shared by all
(left writeable, as a read-only array would be another type to Numba, compiling every walk again)."""


def prepare_rays(origins, directions, t_min=0.0, t_max=np.inf, *, compact: bool = False,
                 check: bool = True, keep_float32: bool = False, shared_origin: bool = False) -> RayBatch:
    """Validate and convert a ray batch once, at the Python boundary; a compact
    :class:`RayBatch` when ``compact``.

    Raises ``ValueError`` for NaN or infinite coordinates, mismatched shapes,
    NaN limits, and zero-length directions: a ray without a direction has no
    defined first hit, so it is an error rather than a silent miss. Without ``check``
    the coordinates and directions are left for the walk to test
    (:func:`rayaccel._validate.unusable_ray`), which saves reading them twice. With
    ``keep_float32``, origins and directions that are both float32 stay float32, for walks
    that read them through :func:`ray_at`. With ``shared_origin``, one origin given for many
    directions (one row, or a broadcast array whose rows alias one) stays one, of shape (3,),
    for walks that read it through :func:`origin_at`; else it is copied to every ray.
    """
    origins = as_points("origins", _one_row_if_repeated(origins), allow_empty=True, check_finite=False,
                        keep_float32=keep_float32)
    directions = as_points("directions", directions, allow_empty=True, check_finite=False, keep_float32=keep_float32)
    if origins.dtype != directions.dtype:
        origins, directions = np.asarray(origins, dtype=np.float64), np.asarray(directions, dtype=np.float64)
    if origins.shape != directions.shape:
        if len(origins) != 1:
            raise ValueError(
                f"origins {origins.shape} and directions {directions.shape} must have the same shape"
            )
        origins = origins[0] if shared_origin else _per_ray(origins, directions)
    if check:
        check_ray_arrays(origins, directions)
    n = len(directions)
    hit_slot = _IN_ORDER if compact else np.arange(n, dtype=np.int64)
    return RayBatch(origins, directions, as_per_ray("t_min", t_min, n, shared=compact),
                    as_per_ray("t_max", t_max, n, shared=compact), hit_slot)


@inline_kernel
def ray_at(origins, directions, i):
    """Ray ``i``'s origin (:func:`origin_at`) and direction as six float64 numbers, from float64 or
    float32 arrays: a float32 coordinate widens to float64 exactly, so a walk computes the same bits
    from float32 rays as from their float64 copy. ``i`` indexes unsigned (:data:`rayaccel._jit.unsigned`), as in
    :func:`ray_limit` and :func:`result_row`: a ray's index is never negative, and Numba's
    wrap-around of negative indices cost each read a few instructions."""
    r = unsigned(i)
    ox, oy, oz = origin_at(origins, r)
    return ox, oy, oz, np.float64(directions[r, 0]), np.float64(directions[r, 1]), np.float64(directions[r, 2])


@inline_kernel
def ray_limit(limits, i):
    """Ray ``i``'s entry of a batch's ``t_min`` or ``t_max``, which may hold one value for all."""
    return limits[unsigned(i) if limits.shape[0] > 1 else unsigned(0)]


@inline_kernel
def result_row(hit_slot, i):
    """The row of the results that takes ray ``i``'s answer: ``hit_slot[i]``, or ``i`` when the
    batch's ``hit_slot`` is empty."""
    return hit_slot[unsigned(i)] if hit_slot.shape[0] > 0 else i


class Camera:
    """A pinhole camera.

    Parameters
    ----------
    eye, target, up : (3,) array_like
        Position, point looked at, and the world's up direction.
    fov : float
        Vertical field of view in degrees.
    """

    def __init__(self, eye, target, up=(0.0, 1.0, 0.0), fov: float = 40.0):
        self.eye = as_points("eye", eye)[0]
        self.target = as_points("target", target)[0]
        self.up = as_points("up", up)[0]
        if not 0.0 < fov < 180.0:
            raise ValueError(f"fov must lie in (0, 180) degrees, got {fov}")
        self.fov = float(fov)
        forward = self.target - self.eye
        if not forward.any():
            raise ValueError("camera eye and target coincide")
        self.forward = forward / np.linalg.norm(forward)
        right = np.cross(self.forward, self.up)
        if np.linalg.norm(right) < 1e-12:
            right = np.cross(self.forward, np.array([1.0, 0.0, 0.0]))
            if np.linalg.norm(right) < 1e-12:
                right = np.cross(self.forward, np.array([0.0, 0.0, 1.0]))
        self.right = right / np.linalg.norm(right)
        self.true_up = np.cross(self.right, self.forward)

    @classmethod
    def framing(cls, lo, hi, view=(0.35, 0.3, 1.0), up=(0.0, 1.0, 0.0), fov: float = 40.0) -> Camera:
        """A camera that sees the whole box ``[lo, hi]`` from direction ``view``."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        center = 0.5 * (lo + hi)
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-9)
        view = np.asarray(view, float)
        distance = radius / np.sin(np.radians(fov) / 2.0) * 1.02
        return cls(center + distance * view / np.linalg.norm(view), center, up, fov)

    @classmethod
    def filling(cls, points, view=(0.35, 0.3, 1.0), up=(0.0, 1.0, 0.0)) -> Camera:
        """A camera looking from direction ``view`` whose square image the ``points`` (n, 3)
        just fill: aimed at the middle of their projection, with the field of view of its
        larger side (2 % margin), from the distance :meth:`framing` would take."""
        points = as_points("points", points)
        lo, hi = points.min(axis=0), points.max(axis=0)
        camera = cls.framing(lo, hi, view, up)
        for _ in range(2):
            relative = points - camera.eye
            depth = relative @ camera.forward
            x = (relative @ camera.right) / depth
            y = (relative @ camera.true_up) / depth
            middle = (0.5 * (x.min() + x.max())) * camera.right + (0.5 * (y.min() + y.max())) * camera.true_up
            half = 1.02 * max(x.max() - x.min(), y.max() - y.min()) / 2.0
            camera = cls(camera.eye, camera.eye + camera.forward + middle, up, float(np.degrees(2.0 * np.arctan(half))))
        return camera

    def rays(self, width: int, height: int, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions through pixel centres, row-major from the top left.

        ``pixels`` selects flat pixel indices; all pixels when None. The origins are the eye
        broadcast to every ray, a read-only view of three numbers, which the queries take as
        one origin (:func:`prepare_rays`) rather than a copy per ray.
        """
        if pixels is None:
            pixels = np.arange(width * height)
        row, col = np.divmod(np.asarray(pixels, dtype=np.int64), width)
        half_h = np.tan(np.radians(self.fov) / 2.0)
        half_w = half_h * width / height
        x = ((col + 0.5) / width * 2.0 - 1.0) * half_w
        y = (1.0 - (row + 0.5) / height * 2.0) * half_h
        directions = self.forward + x[:, None] * self.right + y[:, None] * self.true_up
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.broadcast_to(self.eye, directions.shape)
        return origins, directions


def random_lines(lo, hi, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random lines through the box ``[lo, hi]``, as rays that start outside it: origins
    and unit directions.

    The lines are isotropic and uniform (the measure of integral geometry, Santalo 1976):
    a direction uniform on the sphere, then a point uniform in the disk that bounds the
    box's projection along it; lines that miss the box are drawn again. Under this measure
    a line meets a convex body inside the box with probability proportional to its
    surface area (Cauchy and Crofton), the probability the surface area heuristic assumes.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    center, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-300)
    rng = np.random.default_rng(seed)
    origins, directions = [], []
    found = 0
    while found < n:
        d = rng.normal(size=(2 * (n - found) + 16, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        offset = rng.normal(size=d.shape)
        offset -= (offset * d).sum(axis=1, keepdims=True) * d
        offset *= (radius * np.sqrt(rng.random(len(d))) / np.linalg.norm(offset, axis=1))[:, None]
        o = center + offset - 2.0 * radius * d
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (lo - o) / d, (hi - o) / d
        enter = np.nanmax(np.minimum(t0, t1), axis=1)
        leave = np.nanmin(np.maximum(t0, t1), axis=1)
        keep = enter <= leave
        origins.append(o[keep])
        directions.append(d[keep])
        found += int(keep.sum())
    return np.concatenate(origins)[:n], np.concatenate(directions)[:n]
