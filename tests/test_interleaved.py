"""The walks with several rays in flight per thread (the eight-wide BVH's and the kd-tree's) give
each ray the answer brute force gives it, and the same work counters as the walks of one ray at a
time."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    assert_counts_and_lists_match,
    assert_same_hits,
    axis_parallel_rays,
    camera_rays,
    random_rays,
    vertex_and_edge_rays,
)

import rayaccel as ra
from rayaccel.ray_order import interleaving_pays, second_level_cache_bytes
from rayaccel.rays import prepare_rays
from rayaccel.structures.bvh import accelerator
from rayaccel.structures.bvh.traverse_interleaved import SLOTS
from rayaccel.structures.kdtree import accelerator as kdtree_accelerator
from rayaccel.structures.kdtree.traverse_interleaved import SLOTS as KDTREE_SLOTS


@pytest.fixture
def every_batch_interleaved(monkeypatch):
    """Small trees and every kind of batch take the interleaved walks."""
    for module in (accelerator, kdtree_accelerator):
        monkeypatch.setattr(module, "interleaving_pays", lambda batch, lo, hi, nbytes, sampled, **_: True)


def brute_interleaved_single(scene, method="bvh-binned", **options):
    return (ra.build(scene, "none"), ra.build(scene, method, **options),
            ra.build(scene, method, interleave=False, **options))


# The kd-tree walked eight-wide takes the BVH's walks; walked two-wide, its own.
WALKED = [("bvh-binned", {}), ("kdtree", {}), ("kdtree", {"width": 2})]


def with_own_intervals(origins, seed=5):
    """Each ray's own ``[t_min, t_max]``: some start past zero, half end at a finite distance."""
    rng = np.random.default_rng(seed)
    t_min = rng.choice([0.0, 0.2, 0.5], len(origins))
    t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, t_min + rng.uniform(0.0, 2.0, len(origins)))
    return t_min, t_max


@pytest.mark.parametrize("rays", ["random", "vertices_and_edges", "axis_parallel", "camera"])
@pytest.mark.parametrize(("method", "options"), [*WALKED, ("bvh-sah", {})])
def test_interleaved_walk_matches_brute_force(small_dragon, every_batch_interleaved, rays, method, options):
    """Rays in every direction (many starting outside the tree's box, many missing it), aimed
    exactly at vertices and edges, along the axes with zero components of either sign, and a
    camera's; each with its own interval."""
    make = {"random": random_rays, "vertices_and_edges": vertex_and_edge_rays, "axis_parallel": axis_parallel_rays,
            "camera": lambda scene, n, seed: camera_rays(scene, 64)}
    origins, directions = make[rays](small_dragon, 3001, seed=3)
    t_min, t_max = with_own_intervals(origins)
    brute, interleaved, single = brute_interleaved_single(small_dragon, method, **options)
    reference = brute.intersect(origins, directions, t_min, t_max)
    assert_same_hits(reference, interleaved.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(interleaved.occluded(origins, directions, t_min, t_max), reference.hit)
    np.testing.assert_array_equal(interleaved.intersect(origins, directions, t_min, t_max, any_hit=True).hit,
                                  reference.hit)
    for any_hit in (False, True):
        walked = interleaved.intersect(origins, directions, t_min, t_max, any_hit=any_hit, counters=True).counters
        alone = single.intersect(origins, directions, t_min, t_max, any_hit=any_hit, counters=True).counters
        for name in walked._fields:
            np.testing.assert_array_equal(getattr(walked, name), getattr(alone, name), err_msg=name)


@pytest.mark.parametrize("n", sorted({1, 2, 3 * SLOTS + 5} | {SLOTS + k for k in (-1, 0, 1)}
                                      | {KDTREE_SLOTS + k for k in (-1, 0, 1)}))
@pytest.mark.parametrize(("method", "options"), WALKED)
def test_batches_with_fewer_rays_than_slots(small_dragon, every_batch_interleaved, n, method, options):
    """Batches that leave slots free from the start or free them one by one at the end,
    with rays that miss the tree's box among them."""
    origins, directions = random_rays(small_dragon, n, seed=n)
    origins[::3] = small_dragon.bounds().scene_hi + 1.0
    directions[::3] = [1.0, 0.5, 0.25]
    brute, interleaved, _ = brute_interleaved_single(small_dragon, method, **options)
    reference = brute.intersect(origins, directions)
    assert_same_hits(reference, interleaved.intersect(origins, directions))
    np.testing.assert_array_equal(interleaved.occluded(origins, directions), reference.hit)


@pytest.mark.parametrize(("method", "options"), WALKED)
def test_interleaved_spheres_match_brute_force(spheres, every_batch_interleaved, method, options):
    """Closest and any hit on spheres (the walk's steps do not depend on the primitive kind; counting
    and listing through it are tested on the mesh, which spares compiling their kernel for spheres)."""
    origins, directions = random_rays(spheres, 2000, seed=4)
    t_min, t_max = with_own_intervals(origins)
    brute, interleaved, _ = brute_interleaved_single(spheres, method, **options)
    reference = brute.intersect(origins, directions, t_min, t_max)
    assert_same_hits(reference, interleaved.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(interleaved.occluded(origins, directions, t_min, t_max), reference.hit)


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree"])
def test_interleaved_count_list_and_contains(small_dragon, every_batch_interleaved, method):
    """Counting, listing (all hits and the nearest few) and the inside test, whose ray per point
    counts signed crossings, through the interleaved walk (the kd-tree's counts one ray at a time:
    its rays in flight would share the thread's mailbox row)."""
    origins, directions = random_rays(small_dragon, 1500, seed=9)
    brute, interleaved, single = brute_interleaved_single(small_dragon, method)
    assert_counts_and_lists_match(brute, interleaved, origins, directions)
    points = origins[:500]
    np.testing.assert_array_equal(interleaved.contains(points), single.contains(points))


def test_which_batches_are_interleaved(small_dragon):
    """Incoherent rays through a tree beyond four second-level caches (or as many as the caller
    asks) are interleaved; the same rays through a tree that fits, and camera and shadow rays
    whose neighbours start close and head alike, are not. Rays from one point in every
    direction are."""
    b = small_dragon.bounds()
    big, small = 5 * second_level_cache_bytes(), second_level_cache_bytes()
    incoherent = prepare_rays(*random_rays(small_dragon, 5000))
    assert interleaving_pays(incoherent, b.scene_lo, b.scene_hi, big)
    assert not interleaving_pays(incoherent, b.scene_lo, b.scene_hi, small)
    assert not interleaving_pays(incoherent, b.scene_lo, b.scene_hi, big, caches=5)
    assert interleaving_pays(incoherent, b.scene_lo, b.scene_hi, 6 * second_level_cache_bytes(), caches=5)
    origins, directions = camera_rays(small_dragon, 256)
    assert not interleaving_pays(prepare_rays(origins, directions), b.scene_lo, b.scene_hi, big)
    hits = ra.build(small_dragon, "bvh-binned").intersect(origins, directions)
    points = origins[hits.hit] + hits.t[hits.hit, None] * directions[hits.hit]
    to_light = (b.scene_hi + 1.0) - points
    assert not interleaving_pays(prepare_rays(points, to_light, 1e-4, 1.0), b.scene_lo, b.scene_hi, big)
    around = np.random.default_rng(2).normal(size=(5000, 3))
    assert interleaving_pays(prepare_rays(np.zeros((5000, 3)), around), b.scene_lo, b.scene_hi, big)


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree"])
def test_interleave_option(small_dragon, method):
    assert ra.build(small_dragon, method).options["interleave"] is True
    with pytest.raises(TypeError, match="interleave"):
        ra.build(small_dragon, method, interleave=1)
