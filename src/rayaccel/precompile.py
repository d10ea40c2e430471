"""Filling Numba's cache on every core: the kernels of several methods compiled side by side.

Numba compiles a kernel on its first call, on one core, and caches it on disk
(:mod:`rayaccel._jit`). The methods' kernels are independent of each other, so
on an empty cache one process per core warms up a share of the methods
(:func:`rayaccel.render.warm_up`: a build and a render with shadows on small
scenes), and the calling process then loads what they wrote. The gain is not
measured on an idle machine yet; on one loaded by other work (load 6-9), two
workers took as long as one. Worker processes are spawned,
not forked, since a forked copy of a process whose Numba threads are running
may deadlock.

Spawning workers only pays on an empty cache; a stamp file beside the cache
(``rayaccel-compiled.json``) records which methods and kinds were compiled from
which sources (paths, sizes and modification times of the package's files, and
Numba's version), so that a later call with nothing new to compile loads the
kernels in this process at once.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

__all__ = ["compile_kernels", "default_workers"]

# The methods whose first use compiles the most, first, so that no core is left with a long one at the end.
_SLOWEST_FIRST = ("kdtree", "bvh-binned", "octree", "grid-bvh", "hgrid", "bvh-sah", "bvh-agglomerative", "grid")


def default_workers() -> int:
    """One worker per core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _warm(method: str, kinds: tuple) -> str:
    from .render import warm_up

    warm_up([method], kinds)
    return method


def _sources_key() -> str:
    """A fingerprint of the package's sources and Numba's version."""
    import numba

    digest = hashlib.sha256(numba.__version__.encode())
    for path in sorted(Path(__file__).resolve().parent.rglob("*.py")):
        info = path.stat()
        digest.update(f"{path}|{info.st_size}|{info.st_mtime_ns}".encode())
    return digest.hexdigest()


def _stamp_path() -> Path:
    cache = os.environ.get("NUMBA_CACHE_DIR")
    folder = Path(cache) if cache else Path(__file__).resolve().parent / "__pycache__"
    return folder / "rayaccel-compiled.json"


def _compiled(key: str) -> set:
    try:
        stamp = json.loads(_stamp_path().read_text())
    except (OSError, ValueError):
        return set()
    return set(map(tuple, stamp.get("compiled", []))) if isinstance(stamp, dict) and stamp.get("key") == key else set()


def _record(key: str, pairs: set) -> None:
    try:
        _stamp_path().parent.mkdir(parents=True, exist_ok=True)
        _stamp_path().write_text(json.dumps({"key": key, "compiled": sorted(map(list, pairs))}))
    except OSError:
        pass


def compile_kernels(methods, kinds, workers: int | None = None, progress=None) -> None:
    """Compile (or find in the cache) the kernels of ``methods`` for the primitive ``kinds``,
    on ``workers`` processes (default: one per core); ``progress(done, total)`` after each
    method. With one worker, one method left to compile, or none, it runs in this process."""
    from .render import warm_up

    methods = sorted(methods, key=lambda m: _SLOWEST_FIRST.index(m) if m in _SLOWEST_FIRST else len(_SLOWEST_FIRST))
    workers = default_workers() if workers is None else workers
    key = _sources_key()
    done_before = _compiled(key)
    missing = [m for m in methods if any((m, int(kind)) not in done_before for kind in kinds)]
    if workers <= 1 or len(missing) <= 1:
        warm_up(methods, kinds, progress=progress)
        _record(key, done_before | {(m, int(kind)) for m in methods for kind in kinds})
        return
    with ProcessPoolExecutor(min(workers, len(methods)), mp_context=multiprocessing.get_context("spawn")) as pool:
        pending = [pool.submit(_warm, method, tuple(kinds)) for method in missing]
        for done, future in enumerate(as_completed(pending), 1):
            future.result()
            if progress is not None:
                progress(done, len(missing))
    warm_up(methods, kinds)
    _record(key, done_before | {(m, int(kind)) for m in methods for kind in kinds})
