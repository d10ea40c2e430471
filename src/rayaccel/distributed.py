"""More rays than one machine: the queries on Dask arrays, and frames rendered in tiles over a Dask cluster.

Dask (https://docs.dask.org) is the optional engine (``pip install "rayaccel[dask]"``): ``dask.array``
holds the ray batches, ``distributed`` runs them on a cluster. This module only calls the public
queries (:meth:`Accelerator.intersect`, :meth:`Accelerator.occluded`, :meth:`Accelerator.count`,
:meth:`Accelerator.intersect_all` and the point queries
:meth:`closest_point`, :meth:`distance`, :meth:`winding_number`, :meth:`contains`,
:meth:`signed_distance`) and the renderer's :func:`rayaccel.render.render_pixels`, one call per chunk of
rays or tile of pixels.

The structure travels once. With a ``distributed.Client`` active, the accelerator is scattered to
every worker (``Client.scatter(..., broadcast=True)``, which Dask's best practices recommend for
large objects that many tasks use) the first time a query on Dask arrays or a tiled render needs it
on that client; the graph refers to the resulting future, so no task carries the structure.
Without a client, the graph holds the accelerator under one key, which every chunk's task reads
(threaded scheduler: no copy at all).

Each task runs the kernels on as many Numba threads as its share of the cores (``kernel_threads``):
on a worker of ``k`` threads, ``k`` tasks run at once on one kernel thread each; on the threaded
scheduler, Numba's threads are divided among the scheduler's threads. Otherwise every task would
start a Numba thread per core, and two workers on two cores would run four threads.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import threading
import uuid
import weakref

import numpy as np

from ._jit import max_threads, set_threads, thread_count
from .points import ClosestPoints, check_accuracy, check_max_distance
from .rays import AllHits, Hits, RayCounters
from .render import _BAND_ROWS, RenderResult, assemble, default_camera, default_lights, render_pixels

__all__ = ["is_dask_array", "intersect", "occluded", "count", "intersect_all", "closest_point", "distance",
           "winding_number", "contains", "signed_distance", "ship", "connect", "render"]

_INSTALL = 'pip install "rayaccel[dask]"'
_HIT_FIELDS = [("t", np.float64), ("prim", np.int64), ("u", np.float64), ("v", np.float64), ("geom", np.int64)]
_COUNTER_FIELDS = [(name, np.int64) for name in RayCounters._fields]
_SHIPPED = weakref.WeakKeyDictionary()
_ARRAY_QUERIES = {"occluded": np.dtype(bool), "count": np.dtype(np.int64), "intersect_all": None}
_ALL_FIELDS = [("t", np.float64), ("prim", np.int64), ("u", np.float64), ("v", np.float64), ("geom", np.int64)]


def is_dask_array(value) -> bool:
    """Whether ``value`` is a Dask collection, decided without importing Dask."""
    return type(value).__module__.split(".")[0] == "dask"


def _require(module: str):
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(f"rayaccel's Dask support needs {module!r}: {_INSTALL} ({exc})") from None


def _active_client():
    """The current ``distributed.Client``, or None (also when ``distributed`` was never imported)."""
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return None
    try:
        return distributed.get_client()
    except ValueError:
        return None


def ship(accel, client=None):
    """The accelerator as every task should refer to it: a future of its copy scattered to every worker of
    ``client`` (the active client when None), made once per accelerator and client and made again only when
    the cluster lost it (a restart); without a client, a ``dask.delayed`` holding it under one key."""
    client = client or _active_client()
    shipped = _SHIPPED.setdefault(accel, {})
    if client is None:
        delayed = _require("dask").delayed
        name = shipped.setdefault(None, f"rayaccel-{accel.method}-{uuid.uuid4().hex}")
        return delayed(accel, name=name, traverse=False)
    future = shipped.get(client.id)
    if future is None or future.status != "finished":
        future = shipped[client.id] = client.scatter(accel, broadcast=True, hash=False)
    return future


@contextlib.contextmanager
def _kernel_threads(threads):
    """Run the block with ``threads`` Numba threads on this OS thread (Numba's count is per thread):
    an int, None to leave it, or "match" for this thread's share of the cores (see the module's
    docstring); the count before is restored afterwards."""
    if threads == "match":
        distributed = sys.modules.get("distributed")
        worker = None
        if distributed is not None:
            try:
                worker = distributed.get_worker()
            except ValueError:
                worker = None
        if worker is not None:
            threads = 1
        elif threading.current_thread() is threading.main_thread():
            threads = None
        else:
            import dask

            pool = dask.config.get("num_workers", None) or os.cpu_count() or 1
            threads = max(1, max_threads() // pool)
    if threads is None:
        yield
        return
    before = thread_count()
    set_threads(min(int(threads), max_threads()))
    try:
        yield
    finally:
        set_threads(before)


def _query_block(accel, query, options, threads, origins, directions, t_min, t_max):
    with _kernel_threads(threads):
        result = getattr(accel, query)(origins, directions, t_min, t_max, **options)
    if query in _ARRAY_QUERIES:
        return result
    packed = np.empty(len(result.t), dtype=_hits_dtype(result.counters is not None))
    for name, _ in _HIT_FIELDS:
        packed[name] = getattr(result, name)
    if result.counters is not None:
        for name, _ in _COUNTER_FIELDS:
            packed[name] = getattr(result.counters, name)
    return packed


def _hits_dtype(counters: bool) -> np.dtype:
    return np.dtype(_HIT_FIELDS + (_COUNTER_FIELDS if counters else []))


def _unknown(chunks) -> bool:
    return any(np.isnan(c) for c in chunks)


def _rays(da, origins, directions):
    """Origins and directions as (n, 3) Dask arrays chunked alike along the rays, one chunk across."""
    inputs = {"origins": origins, "directions": directions}
    arrays = {}
    for name, value in inputs.items():
        array = value if is_dask_array(value) else np.asarray(value)
        if array.dtype == object or not (np.issubdtype(array.dtype, np.floating)
                                         or np.issubdtype(array.dtype, np.integer)):
            raise TypeError(f"{name} must hold real numbers, got dtype {array.dtype}")
        if array.ndim == 1 and array.shape[0] == 3:
            array = array[None, :]
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"{name} must have shape (n, 3), got {array.shape}")
        if is_dask_array(array) and _unknown(array.chunks[0]):
            raise ValueError(f"{name} has unknown chunk sizes; call its compute_chunk_sizes() first")
        arrays[name] = array
    origins, directions = arrays["origins"], arrays["directions"]
    n = directions.shape[0]
    if origins.shape[0] != n and origins.shape[0] != 1:
        raise ValueError(f"origins {origins.shape} and directions {directions.shape} must have the same shape")
    reference = [a for a in (directions, origins) if is_dask_array(a) and a.shape[0] == n]
    return origins, directions, reference[0].chunks[0] if reference else None


def _per_ray(da, name, value, n, rows):
    """``(array, index)`` for blockwise: a float and None for a scalar, else an (n,) Dask array chunked as the rays."""
    if not is_dask_array(value):
        array = np.asarray(value, dtype=np.float64)
        if array.ndim == 0:
            if np.isnan(array):
                raise ValueError(f"{name} contains NaN")
            return float(array), None
    else:
        array = value
    if array.ndim == 0:
        array = da.broadcast_to(array, (n,))
    if array.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {array.shape}")
    return _chunked(da, array, (rows,)), "i"


def _chunked(da, array, chunks):
    if is_dask_array(array):
        if _unknown(array.chunks[0]):
            raise ValueError("an input has unknown chunk sizes; call its compute_chunk_sizes() first")
        return array.rechunk(chunks)
    return da.from_array(np.ascontiguousarray(array), chunks=chunks)


def _inputs(da, origins, directions, t_min, t_max, kernel_threads):
    """The rays as Dask arrays chunked alike (origins, directions (n, 3); t_min, t_max (n,) or floats,
    each with its blockwise index, None for a float)."""
    if not (kernel_threads is None or kernel_threads == "match"
            or (isinstance(kernel_threads, (int, np.integer)) and not isinstance(kernel_threads, bool)
                and kernel_threads >= 1)):
        raise ValueError(f'kernel_threads must be "match", None or a count of at least 1, got {kernel_threads!r}')
    origins, directions, rows = _rays(da, origins, directions)
    n = directions.shape[0]
    if rows is None:
        limits = [v for v in (t_min, t_max) if is_dask_array(v) and v.ndim == 1]
        rows = limits[0].chunks[0] if limits else da.core.normalize_chunks("auto", (n,), dtype=np.float64)[0]
    if origins.shape[0] == 1 and n != 1:
        origins = da.broadcast_to(da.asarray(origins), (n, 3), chunks=(rows, (3,)))
    origins = _chunked(da, origins, (rows, (3,)))
    directions = _chunked(da, directions, (rows, (3,)))
    t_min, min_index = _per_ray(da, "t_min", t_min, n, rows)
    t_max, max_index = _per_ray(da, "t_max", t_max, n, rows)
    return origins, directions, t_min, min_index, t_max, max_index


def _query(accel, query, origins, directions, t_min, t_max, options, kernel_threads):
    da = _require("dask.array")
    origins, directions, t_min, min_index, t_max, max_index = _inputs(da, origins, directions, t_min, t_max,
                                                                      kernel_threads)
    meta = np.empty(0, dtype=_ARRAY_QUERIES[query] if query in _ARRAY_QUERIES
                    else _hits_dtype(options.get("counters", False)))
    return da.blockwise(_query_block, "i", ship(accel), None, query, None, options, None, kernel_threads, None,
                        origins, "ij", directions, "ij", t_min, min_index, t_max, max_index,
                        meta=meta, concatenate=True, name=f"rayaccel-{query}-{uuid.uuid4().hex}")


def intersect(accel, origins, directions, t_min=0.0, t_max=np.inf, *, any_hit=False, counters=False, reorder=True,
              kernel_threads="match") -> Hits:
    """:meth:`Accelerator.intersect` on Dask arrays: a :class:`Hits` of lazy Dask arrays chunked as the rays.

    Parameters
    ----------
    accel : Accelerator
    origins, directions : (n, 3) dask.array or array_like
        Chunked along the rays (axis 0); the chunks of ``directions`` (else of ``origins``) are the
        result's, and the other inputs are rechunked to them. A single origin is broadcast.
    t_min, t_max : float, (n,) array_like or (n,) dask.array
    any_hit, counters, reorder
        As for :meth:`Accelerator.intersect`, applied to each chunk.
    kernel_threads : "match", int or None
        Numba threads per task: "match" (see the module's docstring), a count, or None to leave
        Numba's setting alone.

    Each chunk is traced by one task, which produces all the fields; compute them together
    (``dask.compute(hits.t, hits.prim)``), or the chunk is traced once per computation. Shapes are
    checked now; invalid values (NaN, zero directions) raise when computed.
    """
    options = dict(any_hit=bool(any_hit), counters=bool(counters), reorder=bool(reorder))
    packed = _query(accel, "intersect", origins, directions, t_min, t_max, options, kernel_threads)
    ray_counters = RayCounters(*(packed[name] for name, _ in _COUNTER_FIELDS)) if counters else None
    return Hits(packed["t"], packed["prim"], packed["u"], packed["v"], ray_counters, packed["geom"])


def occluded(accel, origins, directions, t_min=0.0, t_max=np.inf, *, reorder=True, kernel_threads="match"):
    """:meth:`Accelerator.occluded` on Dask arrays: a lazy (n,) bool Dask array chunked as the rays
    (inputs and ``kernel_threads`` as for :func:`intersect`)."""
    return _query(accel, "occluded", origins, directions, t_min, t_max, dict(reorder=bool(reorder)), kernel_threads)


def count(accel, origins, directions, t_min=0.0, t_max=np.inf, *, reorder=True, kernel_threads="match"):
    """:meth:`Accelerator.count` on Dask arrays: a lazy (n,) int64 Dask array chunked as the rays
    (inputs and ``kernel_threads`` as for :func:`intersect`)."""
    return _query(accel, "count", origins, directions, t_min, t_max, dict(reorder=bool(reorder)), kernel_threads)


def _block_piece(found, name):
    return np.diff(found.offsets) if name == "counts" else getattr(found, name)


def intersect_all(accel, origins, directions, t_min=0.0, t_max=np.inf, *, max_hits=None, reorder=True,
                  kernel_threads="match") -> AllHits:
    """:meth:`Accelerator.intersect_all` on Dask arrays: an :class:`AllHits` of lazy Dask arrays.

    One task per chunk of rays runs the query; ``offsets`` (n + 1,) is the running sum of
    the chunks' hit counts, and the flat fields are chunked by the chunks of rays, with
    sizes known once computed (``compute_chunk_sizes()``). Compute the fields together
    (``dask.compute(hits.offsets, hits.t)``), or the chunks are traced once per computation.
    Inputs and ``kernel_threads`` as for :func:`intersect`.
    """
    da = _require("dask.array")
    delayed = _require("dask").delayed
    origins, directions, t_min, min_index, t_max, max_index = _inputs(da, origins, directions, t_min, t_max,
                                                                      kernel_threads)
    structure = ship(accel)
    options = dict(max_hits=max_hits, reorder=bool(reorder))
    blocks = zip(origins.to_delayed().ravel(), directions.to_delayed().ravel(),
                 t_min.to_delayed().ravel() if min_index else [t_min] * origins.numblocks[0],
                 t_max.to_delayed().ravel() if max_index else [t_max] * origins.numblocks[0])
    found = [delayed(_query_block, pure=True)(structure, "intersect_all", options, kernel_threads, *block)
             for block in blocks]
    sizes = origins.chunks[0]
    counts = da.concatenate([da.from_delayed(delayed(_block_piece)(piece, "counts"), (size,), dtype=np.int64)
                             for piece, size in zip(found, sizes)])
    offsets = da.concatenate([da.zeros(1, dtype=np.int64, chunks=1), da.cumsum(counts)])
    fields = {name: da.concatenate([da.from_delayed(delayed(_block_piece)(piece, name), (np.nan,), dtype=dtype)
                                    for piece in found]) for name, dtype in _ALL_FIELDS}
    return AllHits(offsets, **fields)


_CLOSEST_FIELDS = [("x", np.float64), ("y", np.float64), ("z", np.float64), ("distance", np.float64),
                   ("prim", np.int64), ("u", np.float64), ("v", np.float64), ("geom", np.int64)]
_POINT_RESULT = {"distance": np.float64, "winding_number": np.float64, "contains": bool, "signed_distance": np.float64}


def _point_block(accel, query, options, threads, points):
    with _kernel_threads(threads):
        result = getattr(accel, query)(points, **options)
    if query != "closest_point":
        return result
    packed = np.empty(len(result.distance), dtype=np.dtype(_CLOSEST_FIELDS))
    for k, name in enumerate("xyz"):
        packed[name] = result.point[:, k]
    for name, _ in _CLOSEST_FIELDS[3:]:
        packed[name] = getattr(result, name)
    return packed


def _point_query(accel, query, points, options, kernel_threads):
    """One task per chunk of query points calling the public point query ``query``."""
    da = _require("dask.array")
    array = points if is_dask_array(points) else np.asarray(points)
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"points must hold real numbers, got dtype {array.dtype}")
    if array.ndim == 1 and array.shape[0] == 3:
        array = array[None, :]
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {array.shape}")
    if is_dask_array(array):
        if _unknown(array.chunks[0]):
            raise ValueError("points has unknown chunk sizes; call its compute_chunk_sizes() first")
        rows = array.chunks[0]
    else:
        rows = da.core.normalize_chunks("auto", (array.shape[0],), dtype=np.float64)[0]
    array = _chunked(da, array, (rows, (3,)))
    meta = np.empty(0, dtype=np.dtype(_CLOSEST_FIELDS) if query == "closest_point" else _POINT_RESULT[query])
    return da.blockwise(_point_block, "i", ship(accel), None, query, None, options, None, kernel_threads, None,
                        array, "ij", meta=meta, concatenate=True, name=f"rayaccel-{query}-{uuid.uuid4().hex}")


def closest_point(accel, points, max_distance=np.inf, *, kernel_threads="match") -> ClosestPoints:
    """:meth:`Accelerator.closest_point` on Dask arrays: a :class:`ClosestPoints` of lazy Dask arrays
    chunked as ``points`` (an (n, 3) Dask array chunked along axis 0, or array_like); compute the
    fields together, or the chunk is queried once per computation."""
    da = _require("dask.array")
    packed = _point_query(accel, "closest_point", points, dict(max_distance=check_max_distance(max_distance)),
                          kernel_threads)
    point = da.stack([packed["x"], packed["y"], packed["z"]], axis=1)
    return ClosestPoints(point, packed["distance"], packed["prim"], packed["u"], packed["v"], packed["geom"])


def distance(accel, points, *, kernel_threads="match"):
    """:meth:`Accelerator.distance` on Dask arrays: a lazy (n,) float64 Dask array chunked as ``points``."""
    return _point_query(accel, "distance", points, {}, kernel_threads)


def winding_number(accel, points, *, accuracy=2.0, kernel_threads="match"):
    """:meth:`Accelerator.winding_number` on Dask arrays: a lazy (n,) float64 Dask array chunked as ``points``."""
    return _point_query(accel, "winding_number", points, dict(accuracy=check_accuracy(accuracy)), kernel_threads)


def contains(accel, points, *, accuracy=2.0, kernel_threads="match"):
    """:meth:`Accelerator.contains` on Dask arrays: a lazy (n,) bool Dask array chunked as ``points``."""
    return _point_query(accel, "contains", points, dict(accuracy=check_accuracy(accuracy)), kernel_threads)


def signed_distance(accel, points, *, accuracy=2.0, kernel_threads="match"):
    """:meth:`Accelerator.signed_distance` on Dask arrays: a lazy (n,) float64 Dask array chunked as ``points``."""
    return _point_query(accel, "signed_distance", points, dict(accuracy=check_accuracy(accuracy)), kernel_threads)


@contextlib.contextmanager
def connect(workers: int | None = None, scheduler: str | None = None, threads_per_worker: int | None = None):
    """Yield a ``distributed.Client``: to the scheduler at ``scheduler`` (an existing cluster, e.g.
    ``tcp://host:8786`` from ``dask-scheduler``), or to a new ``LocalCluster`` of ``workers`` processes
    with ``threads_per_worker`` threads each (the cores divided among them when None), closed afterwards."""
    distributed = _require("distributed")
    if (workers is None) == (scheduler is None):
        raise ValueError("give either workers (a local cluster) or scheduler (an address), not both or neither")
    if scheduler is not None:
        with distributed.Client(scheduler) as client:
            yield client
        return
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    threads = threads_per_worker or max(1, (os.cpu_count() or 1) // workers)
    import logging

    with distributed.LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                                  dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
            distributed.Client(cluster) as client:
        yield client


def _render_tile(accel, camera, width, height, lights, shadows, pixels, threads):
    pixels = np.arange(pixels.start, pixels.stop) if isinstance(pixels, range) else pixels
    with _kernel_threads(threads):
        return render_pixels(accel, camera, width, height, lights, shadows, pixels)


def render(accel, camera=None, width: int = 512, height: int = 512, lights=None, *, shadows: bool = True,
           pixels=None, client=None, tile_rows: int = 128, kernel_threads="match", progress=None) -> RenderResult:
    """:func:`rayaccel.render.render` with the frame cut into tiles of ``tile_rows`` rows (rounded up to
    the renderer's bands), each rendered by one task on the cluster of ``client`` (the active one when
    None): the same image, bit for bit, as the local render. ``progress(done_rows, total_rows)`` as
    tiles arrive. The result's ``primary_seconds`` and ``shadow_seconds`` add up the workers' times."""
    distributed = _require("distributed")
    client = client or _active_client()
    if client is None:
        raise ValueError("a tiled render needs a distributed.Client: see rayaccel.distributed.connect")
    camera = camera or default_camera(accel)
    lights = default_lights(accel, camera) if lights is None else np.atleast_2d(np.asarray(lights, float))
    rendered = range(width * height) if pixels is None else np.asarray(pixels, dtype=np.int64).ravel()
    if not isinstance(rendered, range) and len(rendered) and (rendered.min() < 0 or rendered.max() >= width * height):
        raise ValueError(f"pixels must be flat indices in [0, {height * width}) for a {width}x{height} image")
    tile = max(1, -(-int(tile_rows) // _BAND_ROWS)) * _BAND_ROWS * width
    structure = ship(accel, client)
    futures = {client.submit(_render_tile, structure, camera, width, height, lights, shadows, rendered[a:a + tile],
                             kernel_threads, pure=False): a for a in range(0, len(rendered), tile)}
    result, done = None, 0
    for future in distributed.as_completed(futures):
        first = futures.pop(future)
        piece = rendered[first:first + tile]
        result = assemble(future.result(), np.asarray(piece), width, height, result)
        done += len(piece)
        if progress is not None:
            progress(round(height * done / max(len(rendered), 1)), height)
    return result or assemble(render_pixels(accel, camera, width, height, lights, shadows, []), [], width, height)
