"""A walk's chunks on Numba's own threads: every ray once, the answers of the pool, and the pool where unsafe."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from conftest import assert_same_hits, random_rays

import rayaccel as ra
from rayaccel.ray_order import Neighbours
from rayaccel.structures import base, compiled_chunks
from rayaccel.structures.actions import hit_flags
from rayaccel.structures.compiled_chunks import run_chunks


@numba.njit(nogil=True)
def _marking_walk(ray_first, ray_end, tid, seen, chunk_ends, thread_of, action, weight):
    """Marks each ray of its chunk once, the chunk's end at its first ray and the thread that took
    it; returns ``weight`` a ray."""
    for i in range(ray_first, ray_end):
        seen[i] += 1
        thread_of[i] = tid
    chunk_ends[ray_first] = ray_end
    return weight * (ray_end - ray_first)


@numba.njit(nogil=True)
def _walk_answering_nothing(ray_first, ray_end, tid, marks, scale):
    seen, weight = marks
    for i in range(ray_first, ray_end):
        seen[i] += weight * scale


def _marked(n):
    return np.zeros(n, dtype=np.int64), np.full(n, -1, dtype=np.int64), np.full(n, -1, dtype=np.int64)


@pytest.mark.parametrize("n, chunk, align", [(100_000, 4096, 1), (262_144, 8192, 64), (140_001, 4160, 64),
                                             (5, 64, 64)])
def test_every_ray_once_in_aligned_chunks_that_shrink_at_the_end(two_threads, n, chunk, align):
    seen, chunk_ends, thread_of = _marked(n)
    found = run_chunks(_marking_walk, n, chunk, align, 2, (seen, chunk_ends, thread_of, hit_flags(seen > 0), 3))
    assert found == 3 * n
    assert (seen == 1).all()
    assert set(np.unique(thread_of)) <= {0, 1}
    firsts = np.flatnonzero(chunk_ends >= 0)
    sizes = chunk_ends[firsts] - firsts
    assert firsts[0] == 0 and (firsts % align == 0).all()
    assert (chunk_ends[firsts[:-1]] == firsts[1:]).all() and chunk_ends[firsts[-1]] == n
    assert (sizes <= chunk).all()
    if n > 8 * chunk:
        assert (sizes == chunk).sum() > len(sizes) // 2
        assert (sizes < chunk).sum() >= 2


def test_walks_answering_nothing_and_taking_tuples(two_threads):
    """A walk that returns nothing counts as 0; tuples among its arguments reach it whole."""
    n = 50_000
    seen = np.zeros(n, dtype=np.int64)
    assert run_chunks(_walk_answering_nothing, n, 1024, 1, 2, ((seen, 2), 3)) == 0
    assert (seen == 6).all()


def test_the_pool_runs_what_is_not_taken_here(two_threads, monkeypatch):
    """None, having walked nothing: on one thread, for a walk taking a tuple within a tuple or a named
    tuple other than an action, in a forked child of the importing process, under a threading layer
    unsafe for several Python threads."""
    n = 10_000
    seen, chunk_ends, thread_of = _marked(n)
    args = (seen, chunk_ends, thread_of, hit_flags(seen > 0), 1)
    assert run_chunks(_marking_walk, n, 1024, 1, 1, args) is None
    assert run_chunks(_walk_answering_nothing, n, 1024, 1, 2, ((seen, (2,)), 3)) is None
    assert run_chunks(_marking_walk, n, 1024, 1, 2, (*args[:4], Neighbours(1, 1.0, 1.0, 1.0))) is None
    with monkeypatch.context() as patch:
        patch.setattr(compiled_chunks, "_IMPORTED_BY", -1)
        assert run_chunks(_marking_walk, n, 1024, 1, 2, args) is None
    with monkeypatch.context() as patch:
        patch.setattr(compiled_chunks, "_SAFE_LAYERS", ())
        assert run_chunks(_marking_walk, n, 1024, 1, 2, args) is None
    assert (seen == 0).all()
    assert run_chunks(_marking_walk, n, 1024, 1, 2, args) == n and (seen == 1).all()


def _queries(accel, rays):
    return (accel.intersect(*rays, counters=True, reorder=False), accel.intersect(*rays), accel.occluded(*rays),
            accel.count(*rays))


@pytest.mark.parametrize("layout", ["float32 lanes", "indexed"])
def test_large_batches_give_the_hits_and_counters_of_the_pool(small_dragon, two_threads, monkeypatch, layout):
    """Batches large enough to be shared at once (:data:`rayaccel.structures.base.ALONE_FIRST_BELOW`):
    camera rays (the packet walks) and random rays with counters (the walk of one ray at a time)
    and without, hit counts, through every kind of walk, each taking its chunks here, answer as the
    pool's walks do, over a mesh whose leaves keep float32 lanes and one that keeps the indexed
    layout, a tuple among the walks' arguments (:mod:`rayaccel.geometry.gather`)."""
    scene = small_dragon if layout == "float32 lanes" else ra.TriangleMesh(small_dragon.vertices + 1e-9,
                                                                         small_dragon.faces)
    taken = []
    monkeypatch.setattr(base, "run_chunks", lambda *args: taken.append(run_chunks(*args)) or taken[-1])
    box = scene.bounds()
    camera = ra.Camera.framing(box.scene_lo, box.scene_hi).rays(384, 384)
    randoms = random_rays(scene, base.ALONE_FIRST_BELOW + 999, seed=3)
    for method in ("bvh-binned", "kdtree", "grid", "grid-bvh", "octree", "hgrid"):
        accel = ra.build(scene, method)
        for rays in (camera, randoms):
            ours = _queries(accel, rays)
            with monkeypatch.context() as patch:
                patch.setattr(base, "run_chunks", lambda *args: None)
                pools = _queries(accel, rays)
            for mine, theirs in zip(ours[:2], pools[:2]):
                assert_same_hits(mine, theirs)
            np.testing.assert_array_equal(ours[0].counters.tests, pools[0].counters.tests)
            np.testing.assert_array_equal(ours[2], pools[2])
            np.testing.assert_array_equal(ours[3], pools[3])
    assert len(taken) >= 6 * 2 * 3 and all(found is not None for found in taken)
