"""Coherent ray order: sorting a batch changes nothing but the speed."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_same_hits, camera_rays, random_rays

import rayaccel as ra
from rayaccel import ray_order
from rayaccel.ray_order import MIN_RAYS, coherent_batch, last_level_cache_bytes, second_level_cache_bytes, sorting_pays
from rayaccel.rays import Hits, prepare_rays
from rayaccel.structures.bvh.accelerator import BoundingVolumeHierarchy


@pytest.fixture(autouse=True)
def sort_every_structure(monkeypatch):
    """The test scenes fit in any cache, which would leave their rays as given, and the
    eight-wide BVH walk traces as given whatever the size: here every walk is sorted, so that
    each is checked to write its hits through the batch's ``hit_slot``."""
    monkeypatch.setattr(ray_order, "last_level_cache_bytes", lambda: 0)
    monkeypatch.setattr(BoundingVolumeHierarchy, "_walk_gains_from_sorting", property(lambda self: True))


@pytest.fixture(scope="module")
def incoherent_batch(small_dragon):
    origins, directions = random_rays(small_dragon, MIN_RAYS + 4321, seed=3)
    rng = np.random.default_rng(4)
    t_min = rng.uniform(0.0, 0.05, len(origins))
    t_max = rng.choice([np.inf, 0.3], len(origins))
    return origins, directions, t_min, t_max


@pytest.mark.parametrize("method", [m for m in ra.methods() if m != "none"])
def test_sorted_batch_gives_the_same_hits_and_counters(small_dragon, incoherent_batch, method):
    accel = ra.build(small_dragon, method)
    given = accel.intersect(*incoherent_batch, counters=True, reorder=False)
    reordered = accel.intersect(*incoherent_batch, counters=True)
    assert_same_hits(given, reordered)
    for name in ("nodes", "tests", "mailbox_skips"):
        np.testing.assert_array_equal(getattr(reordered.counters, name), getattr(given.counters, name))
    np.testing.assert_array_equal(accel.occluded(*incoherent_batch), accel.occluded(*incoherent_batch, reorder=False))


def test_sorted_batch_agrees_with_brute_force(small_dragon, incoherent_batch):
    subset = slice(None, None, 17)
    reference = ra.build(small_dragon, "none").intersect(*(a[subset] for a in incoherent_batch))
    hits = ra.build(small_dragon, "bvh-binned").intersect(*incoherent_batch)
    assert_same_hits(reference, Hits(hits.t[subset], hits.prim[subset], hits.u[subset], hits.v[subset], None))


@pytest.mark.parametrize("method", ["grid", "bvh-binned"])
def test_sorted_batch_gives_the_same_sphere_coordinates(spheres, method):
    batch = random_rays(spheres, MIN_RAYS + 999, seed=5)
    accel = ra.build(spheres, method)
    reordered = accel.intersect(*batch)
    assert_same_hits(accel.intersect(*batch, reorder=False), reordered)
    subset = slice(None, None, 29)
    assert_same_hits(ra.build(spheres, "none").intersect(*(a[subset] for a in batch)),
                     Hits(*(a[subset] for a in reordered[:4]), None))


def test_sort_is_a_permutation_by_octant_then_origin(small_dragon, incoherent_batch):
    batch = prepare_rays(*incoherent_batch)
    bounds = small_dragon.bounds()
    ordered = coherent_batch(batch, bounds.scene_lo, bounds.scene_hi)
    slot = ordered.hit_slot
    np.testing.assert_array_equal(np.sort(slot), np.arange(len(slot)))
    for given, moved in zip(batch[:4], ordered[:4]):
        np.testing.assert_array_equal(moved, given[slot])
    octant = (ordered.directions < 0) @ np.array([4, 2, 1])
    assert (np.diff(octant) >= 0).all()


def test_coherent_batches_are_left_alone(small_dragon):
    origins, directions = camera_rays(small_dragon, 200)
    batch = prepare_rays(origins, directions)
    bounds = small_dragon.bounds()
    assert coherent_batch(batch, bounds.scene_lo, bounds.scene_hi) is batch


def test_the_eight_wide_bvh_traces_rays_as_given(small_dragon, incoherent_batch, monkeypatch):
    monkeypatch.undo()
    monkeypatch.setattr(ray_order, "last_level_cache_bytes", lambda: 0)
    batch = prepare_rays(*incoherent_batch)
    assert ra.build(small_dragon, "bvh-binned")._ordered(batch, True) is batch
    assert ra.build(small_dragon, "bvh-binned", width=2)._ordered(batch, True) is not batch


def test_structures_within_half_the_cache_trace_rays_as_given(small_dragon, incoherent_batch, monkeypatch):
    accel = ra.build(small_dragon, "kdtree", width=2, interleave=False)
    batch = prepare_rays(*incoherent_batch)
    size = accel.stats()["bytes"]
    monkeypatch.setattr(ray_order, "last_level_cache_bytes", lambda: 2 * size)
    assert accel._ordered(batch, True) is batch
    monkeypatch.setattr(ray_order, "last_level_cache_bytes", lambda: 2 * size - 2)
    assert not np.array_equal(accel._ordered(batch, True).hit_slot, batch.hit_slot)
    assert accel._ordered(batch, False) is batch
    assert not sorting_pays(MIN_RAYS - 1, 2 * size)


def test_kdtree_keeping_rays_in_flight_traces_them_as_given(small_dragon, incoherent_batch, monkeypatch):
    """Rays in flight per thread hide the waits that sorting would: the kd-tree's binary walk sorts
    a large incoherent batch only with ``interleave=False``; its cells walked eight-wide, as the
    BVH's eight-wide walk, never."""
    monkeypatch.setattr(ray_order, "last_level_cache_bytes", lambda: 1024)
    batch = prepare_rays(*incoherent_batch)
    assert ra.build(small_dragon, "kdtree", width=2)._ordered(batch, True) is batch
    assert ra.build(small_dragon, "kdtree", width=2, interleave=False)._ordered(batch, True) is not batch
    assert ra.build(small_dragon, "kdtree", interleave=False)._ordered(batch, True) is batch


def test_cache_sizes_are_read():
    assert last_level_cache_bytes() >= second_level_cache_bytes() >= 64 << 10


@pytest.mark.parametrize("method", [m for m in ra.methods() if m != "none"])
def test_limits_shared_by_every_ray_give_what_per_ray_limits_give(small_dragon, incoherent_batch, method):
    """A query whose ``t_min`` and ``t_max`` are scalars traces a compact batch (one limit for
    all rays, rays in place: :class:`rayaccel.rays.RayBatch`), sorted here as any batch; its
    answers, misses included, are those of the same limits given per ray (the default limits,
    ``0`` and ``inf``, go through compact batches in every other query test)."""
    origins, directions, _, _ = incoherent_batch
    accel = ra.build(small_dragon, method)
    t_min, t_max = 0.02, 0.3
    per_ray = (np.full(len(origins), t_min), np.full(len(origins), t_max))
    shared = accel.intersect(origins, directions, t_min, t_max, counters=True)
    given = accel.intersect(origins, directions, *per_ray, counters=True, reorder=False)
    assert_same_hits(given, shared)
    assert np.isnan(shared.u[~shared.hit]).all() and (shared.t[~shared.hit] == np.inf).all()
    np.testing.assert_array_equal(shared.counters.tests, given.counters.tests)
    np.testing.assert_array_equal(accel.occluded(origins, directions, t_min, t_max),
                                  accel.occluded(origins, directions, *per_ray, reorder=False))


def test_compact_batch_shapes():
    origins, directions = np.zeros((5, 3)), np.ones((5, 3))
    compact = prepare_rays(origins, directions, 0.5, np.inf, compact=True)
    assert compact.t_min.shape == compact.t_max.shape == (1,) and compact.hit_slot.shape == (0,)
    mixed = prepare_rays(origins, directions, np.arange(5.0), 9.0, compact=True)
    assert mixed.t_min.shape == (5,) and mixed.t_max.shape == (1,)
    full = prepare_rays(origins, directions, 0.5, np.inf)
    assert full.t_min.shape == (5,) and (full.hit_slot == np.arange(5)).all()
