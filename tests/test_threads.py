"""Work shared among threads: every item once, scratch rows never shared, results independent of threads."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
from conftest import assert_same_hits, random_rays

import rayaccel as ra
from rayaccel._helper_threads import HelperThreads
from rayaccel._jit import (
    chunk_count,
    helper_wake_seconds,
    lent_rows,
    on_threads,
    set_threads,
    share_among_threads,
    thread_count,
    thread_rows,
)
from rayaccel.structures import base


@pytest.fixture
def two_threads():
    before = thread_count()
    set_threads(2)
    yield
    set_threads(before)


@pytest.mark.parametrize("n, chunk", [(0, 4), (1, 4), (7, 4), (100, 7), (4096, 1024)])
def test_every_item_once_and_rows_never_shared(two_threads, n, chunk):
    seen = np.zeros(n, dtype=np.int64)
    running = set()
    lock = threading.Lock()
    rows_used = set()

    def run(first, end, row):
        with lock:
            assert row not in running
            running.add(row)
            rows_used.add(row)
        time.sleep(0.001)
        seen[first:end] += 1
        with lock:
            running.remove(row)

    share_among_threads(run, n, chunk)
    assert (seen == 1).all()
    assert rows_used <= set(range(chunk_count(n, chunk)))


def test_the_calling_thread_takes_chunks_too(two_threads):
    takers = []

    def run(first, end, row):
        time.sleep(0.002)
        takers.append(threading.get_ident())

    share_among_threads(run, 64, 4)
    assert len(takers) >= 16
    assert threading.get_ident() in takers


@pytest.mark.parametrize("shortest_seconds", [0.0, 10.0])
def test_threads_take_their_own_parts_then_shrinking_chunks(two_threads, shortest_seconds):
    """Each thread takes chunks from the front of its own contiguous part of the items, then,
    its part done, from the back of the part with most left; the chunks keep to the length given
    until the last few a thread, then shrink with the items left, but not below what the last
    chunk's pace gets through in ``shortest_seconds`` (ten seconds here: none shrinks) nor below
    the alignment. Every chunk starts on the alignment and every item is taken once."""
    n, chunk, align = 10_000, 640, 64
    seen = np.zeros(n, dtype=np.int64)
    spans = []
    lock = threading.Lock()

    def run(first, end, row):
        with lock:
            spans.append((first, end, row))
        seen[first:end] += 1
        time.sleep(0.0005)

    share_among_threads(run, n, chunk, align, shortest_seconds)
    assert (seen == 1).all()
    assert all(first % align == 0 and 0 < end - first <= chunk for first, end, _ in spans)
    first_taken = {}
    for first, _, row in spans:
        first_taken.setdefault(row, first)
    assert first_taken[0] == 0 and first_taken.get(1, n // 2 // align * align) == n // 2 // align * align
    lengths = [end - first for first, end, _ in spans]
    assert lengths.count(chunk) >= (n - 2 * 2 * chunk) // chunk - 2
    if shortest_seconds:
        assert len(spans) <= -(-n // chunk) + 3
    else:
        assert min(lengths) <= align and len(spans) > -(-n // chunk) + 3


def _recording_walk(seconds_a_ray: float):
    """A stand-in for a ray walk that records its chunks ``(first, end, tid)``, sleeps
    ``seconds_a_ray`` for each of their rays and returns 1 a chunk."""
    chunks = []

    def walk(first, end, tid, payload):
        assert payload == "payload"
        chunks.append((first, end, tid))
        if seconds_a_ray:
            time.sleep(seconds_a_ray * (end - first))
        return 1

    return walk, chunks


def _every_ray_once_on_aligned_chunks(chunks, n, align):
    seen = np.zeros(n, dtype=np.int64)
    for first, end, _ in chunks:
        assert first % align == 0 and (end % align == 0 or end == n)
        seen[first:end] += 1
    return bool((seen == 1).all())


def test_a_small_batch_of_cheap_rays_stays_on_the_calling_thread(two_threads, monkeypatch):
    """Rays that would take the caller less time than waking a helper costs (a wake of a second
    here) are walked by the caller, in growing chunks that start on multiples of ``align``."""
    monkeypatch.setattr(base, "helper_wake_seconds", lambda: 1.0)
    walk, chunks = _recording_walk(0.0)
    found = base.walk_rays(walk, 50_000, "payload", align=64)
    assert _every_ray_once_on_aligned_chunks(chunks, 50_000, 64)
    assert {tid for _, _, tid in chunks} == {0}
    assert chunks[0][:2] == (0, base.FIRST_CHUNK) and found == len(chunks) < 8


def test_a_small_batch_of_dear_rays_is_shared_with_the_helpers(two_threads, monkeypatch):
    """Once the first chunk shows that the rays left would keep the caller busy for many wakes
    of a helper (a microsecond here), the helpers share them; what each chunk returns is summed."""
    assert 0.0 < helper_wake_seconds() < 0.1
    monkeypatch.setattr(base, "helper_wake_seconds", lambda: 1e-6)
    walk, chunks = _recording_walk(1e-6)
    found = base.walk_rays(walk, 16_384, "payload", align=64)
    assert _every_ray_once_on_aligned_chunks(chunks, 16_384, 64)
    assert chunks[0][:2] == (0, base.FIRST_CHUNK) and found == len(chunks)
    assert {tid for _, _, tid in chunks} == {0, 1}


def test_on_threads_returns_each_chunk_result_in_order(two_threads):
    results = on_threads(lambda first, end, c: (c, first, end), 100, min_chunk=10)
    assert [c for c, _, _ in results] == list(range(len(results))) == [0, 1]
    assert results[0][1] == 0 and results[-1][2] == 100
    assert all(results[c][2] == results[c + 1][1] for c in range(len(results) - 1))


@pytest.mark.parametrize("failing_row", [0, 1])
def test_an_error_is_raised_once_every_chunk_has_ended(two_threads, failing_row):
    running = set()
    started = []
    lock = threading.Lock()

    def run(first, end, row):
        with lock:
            running.add(first)
            started.append(first)
        try:
            time.sleep(0.01)
            if row == failing_row and first > 0:
                raise RuntimeError(f"chunk from {first} failed")
        finally:
            with lock:
                running.discard(first)

    with pytest.raises(RuntimeError, match="failed"):
        share_among_threads(run, 400, 4)
    assert not running
    assert len(started) < 100


def test_walks_give_the_same_hits_on_one_thread_and_in_many_chunks(small_dragon, two_threads):
    origins, directions = random_rays(small_dragon, 50_000, seed=11)
    for method in ("bvh-binned", "kdtree", "grid"):
        accel = ra.build(small_dragon, method)
        shared = accel.intersect(origins, directions, counters=True, reorder=False)
        counts = accel.count(origins, directions, reorder=False)
        set_threads(1)
        alone = accel.intersect(origins, directions, counters=True, reorder=False)
        np.testing.assert_array_equal(accel.count(origins, directions, reorder=False), counts)
        set_threads(2)
        assert_same_hits(alone, shared)
        np.testing.assert_array_equal(alone.counters.tests, shared.counters.tests)


@pytest.mark.parametrize("shape, dtype", [((2, 8), np.float64), ((3, 33), np.int32), ((2, 17, 2), np.float64),
                                          ((4, 5, 7), np.int64)])
def test_thread_rows_start_on_their_own_cache_line_pairs(shape, dtype):
    rows = thread_rows(shape, dtype)
    assert rows.dtype == dtype and rows.flags.c_contiguous and rows.flags.writeable
    assert rows.shape[0] == shape[0] and rows.shape[1] >= shape[1] and rows.shape[2:] == shape[2:]
    assert all(rows[r].ctypes.data % 128 == 0 for r in range(shape[0]))


@pytest.mark.parametrize("method", ["bvh-binned", "bvh-sah", "bvh-median-space"])
def test_builds_on_two_threads_make_the_tree_of_one(small_dragon, two_threads, method):
    """The subtrees built in parallel, their blocks moved together afterwards
    (:func:`rayaccel.structures.bvh.nodes.close_gaps`), form the tree a build on one thread makes:
    the same eight-wide records and leaf order, and a binary layout whose children lie side by
    side after their parent, every primitive in one leaf, tracing the same hits."""
    on_two = ra.build(small_dragon, method)
    binary_on_two = ra.build(small_dragon, method, width=2)
    set_threads(1)
    alone = ra.build(small_dragon, method)
    binary_alone = ra.build(small_dragon, method, width=2)
    set_threads(2)
    np.testing.assert_array_equal(on_two.wide.view(np.int32), alone.wide.view(np.int32))
    np.testing.assert_array_equal(on_two.prim_order, alone.prim_order)
    tree = binary_on_two.bvh
    inner = np.flatnonzero(tree.node_count == 0)
    assert tree.n_nodes == binary_alone.bvh.n_nodes
    assert (tree.node_first[inner] > inner).all()
    children = np.concatenate([tree.node_first[inner], tree.node_first[inner] + 1])
    assert np.array_equal(np.sort(children), np.arange(1, tree.n_nodes))
    leaves = np.flatnonzero(tree.node_count > 0)
    covered = np.concatenate([np.arange(f, f + c) for f, c in zip(tree.node_first[leaves], tree.node_count[leaves])])
    assert np.array_equal(np.sort(covered), np.arange(len(small_dragon)))
    origins, directions = random_rays(small_dragon, 2000, seed=4)
    assert_same_hits(binary_alone.intersect(origins, directions), binary_on_two.intersect(origins, directions))


def _scratch(rows, width):
    return thread_rows((rows, width)), thread_rows((rows, width), np.int32)


def test_lent_rows_come_back_for_the_next_block_and_are_never_lent_twice():
    """A block gets the scratch the block before it gave back (also after an error); blocks
    within each other or on two Python threads at once each get their own; another key gets
    another set."""
    with lent_rows(_scratch, 2, 40) as first:
        assert [a.shape[:1] for a in first] == [(2,), (2,)] and first[1].dtype == np.int32
        with lent_rows(_scratch, 2, 40) as inner:
            assert all(a is not b for a, b in zip(first, inner))
    with pytest.raises(RuntimeError):
        with lent_rows(_scratch, 2, 40) as again:
            assert again is first or again is inner
            raise RuntimeError("a walk failed")
    with lent_rows(_scratch, 2, 41) as other:
        assert other is not first and other is not inner and other[0].shape[1] >= 41
    held = []
    barrier = threading.Barrier(2)

    def borrow():
        with lent_rows(_scratch, 3, 8) as scratch:
            held.append(scratch)
            barrier.wait()

    workers = [threading.Thread(target=borrow) for _ in range(2)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert held[0] is not held[1]
    with lent_rows(_scratch, 3, 8) as scratch:
        assert any(scratch is h for h in held)


@pytest.mark.parametrize("side, randoms", [(64, 4_000), (384, base.ALONE_FIRST_BELOW + 1)])
def test_queries_on_python_threads_at_once_give_the_hits_of_one(small_dragon, side, randoms):
    """Each query borrows its own per-thread scratch (:func:`rayaccel._jit.lent_rows`), so queries
    running side by side on Python threads answer as each would alone: camera rays (the packet
    walk) and random rays (the walk of one ray at a time), in batches that begin on the calling
    thread alone and in batches shared at once (:data:`rayaccel.structures.base.ALONE_FIRST_BELOW`)."""
    box = small_dragon.bounds()
    batches = [ra.Camera.framing(box.scene_lo, box.scene_hi).rays(side, side),
               random_rays(small_dragon, randoms, seed=5)]
    accel = ra.build(small_dragon, "bvh-binned")
    alone = [(accel.intersect(*rays), accel.occluded(*rays)) for rays in batches]
    results = []

    def query(k):
        for _ in range(4):
            results.append((k, accel.intersect(*batches[k % 2]), accel.occluded(*batches[k % 2])))

    workers = [threading.Thread(target=query, args=(k,)) for k in range(4)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    assert len(results) == 16
    for k, hits, any_hit in results:
        assert_same_hits(alone[k % 2][0], hits)
        np.testing.assert_array_equal(alone[k % 2][1], any_hit)


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs Linux's thread affinity and two CPUs")
@pytest.mark.parametrize("caller_cpu", [0, 1])
def test_a_pass_keeps_the_caller_and_the_helpers_on_different_cpus(caller_cpu):
    caller_may_use = os.sched_getaffinity(0)
    cpu = sorted(caller_may_use)[caller_cpu]
    pool = HelperThreads(3)
    pool._current_cpu = lambda: cpu
    held = pool.begin_pass()
    try:
        assert os.sched_getaffinity(0) == {cpu}
        where_helpers_run = {frozenset(pool.submit(lambda _: os.sched_getaffinity(0), k).result()) for k in range(6)}
        assert pool.begin_pass() is None  # a pass begun meanwhile on another thread changes nothing
        pool.end_pass(None)
    finally:
        pool.end_pass(held)
    assert where_helpers_run == {frozenset(caller_may_use - {cpu})}
    assert os.sched_getaffinity(0) == caller_may_use


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs Linux's thread affinity")
def test_a_pass_gives_the_caller_its_cpus_back_after_an_error(two_threads):
    caller_may_use = os.sched_getaffinity(0)

    def run(first, end, row):
        raise RuntimeError("chunk failed")

    with pytest.raises(RuntimeError, match="chunk failed"):
        share_among_threads(run, 64, 4)
    assert os.sched_getaffinity(0) == caller_may_use


def test_helpers_without_thread_ids_run_wherever_the_system_puts_them():
    pool = HelperThreads(2)
    pool._thread_ids = []
    assert pool.begin_pass() is None
    assert pool.submit(lambda row: row * 3, 5).result() == 15
    pool.end_pass(None)
