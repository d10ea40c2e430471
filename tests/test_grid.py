"""The uniform grid against the brute-force oracle, hit for hit, for every option."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    assert_same_hits,
    axis_parallel_rays,
    camera_rays,
    examples,
    random_rays,
    vertex_and_edge_rays,
)
from hypothesis import given, settings
from hypothesis import strategies as st

import rayaccel as ra
from rayaccel.structures.grid.mailbox import MAX_STAMP, MailboxPool

GRID_OPTIONS = [
    {},
    {"mailbox": False},
    {"insert": "exact"},
    {"insert": "exact", "mailbox": False},
    {"density": 0.5},
    {"density": 40.0, "insert": "exact"},
    {"resolution": 1},
    {"resolution": (7, 1, 13)},
]


def ray_sets(scene):
    return {
        "camera": camera_rays(scene, 48),
        "incoherent": random_rays(scene, 2000),
        "axis-parallel": axis_parallel_rays(scene, 1000),
    }


@pytest.mark.parametrize("options", GRID_OPTIONS, ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "default")
@pytest.mark.parametrize("scene_name", ["small_dragon", "spheres"])
def test_grid_agrees_with_brute_force(scene_name, options, request):
    scene = request.getfixturevalue(scene_name)
    reference = ra.build(scene, "none")
    grid = ra.build(scene, "grid", **options)
    for origins, directions in ray_sets(scene).values():
        assert_same_hits(reference.intersect(origins, directions), grid.intersect(origins, directions))
        np.testing.assert_array_equal(grid.occluded(origins, directions), reference.occluded(origins, directions))


def test_grid_on_bunny(bunny):
    reference = ra.build(bunny, "none")
    origins, directions = camera_rays(bunny, 40)
    for options in ({}, {"insert": "exact"}):
        grid = ra.build(bunny, "grid", **options)
        assert_same_hits(reference.intersect(origins, directions), grid.intersect(origins, directions))


@pytest.mark.parametrize("insert", ["bbox", "exact"])
def test_rays_through_vertices_and_edges(small_dragon, insert):
    origins, directions = vertex_and_edge_rays(small_dragon, 3000)
    reference = ra.build(small_dragon, "none").intersect(origins, directions)
    assert reference.hit.mean() > 0.98  # the rest graze the silhouette
    assert_same_hits(reference, ra.build(small_dragon, "grid", insert=insert).intersect(origins, directions))


def test_rays_starting_on_the_surface_and_inside_the_grid(small_dragon):
    rng = np.random.default_rng(3)
    faces = rng.integers(0, len(small_dragon), 2000)
    weights = rng.dirichlet([1, 1, 1], size=2000)
    corners = small_dragon.geometry[faces].reshape(-1, 3, 3)
    origins = np.einsum("nk,nkj->nj", weights, corners)
    directions = rng.normal(size=(2000, 3))
    reference = ra.build(small_dragon, "none")
    grid = ra.build(small_dragon, "grid")
    for t_min in (0.0, 1e-6):
        assert_same_hits(reference.intersect(origins, directions, t_min=t_min),
                         grid.intersect(origins, directions, t_min=t_min))


def test_t_max_limits_and_per_ray_intervals(spheres):
    origins, directions = random_rays(spheres, 3000, seed=5)
    rng = np.random.default_rng(1)
    t_min = rng.uniform(0.0, 0.2, len(origins))
    t_max = rng.uniform(0.2, 1.5, len(origins))
    reference = ra.build(spheres, "none").intersect(origins, directions, t_min, t_max)
    hits = ra.build(spheres, "grid").intersect(origins, directions, t_min, t_max)
    assert_same_hits(reference, hits)
    assert ((hits.t[hits.hit] >= t_min[hits.hit]) & (hits.t[hits.hit] <= t_max[hits.hit])).all()


def test_counters_and_mailbox_savings(small_dragon):
    origins, directions = camera_rays(small_dragon, 64)
    with_mailbox = ra.build(small_dragon, "grid", density=20).intersect(origins, directions, counters=True)
    without = ra.build(small_dragon, "grid", density=20, mailbox=False).intersect(origins, directions, counters=True)
    np.testing.assert_array_equal(with_mailbox.counters.nodes, without.counters.nodes)
    assert (without.counters.mailbox_skips == 0).all()
    np.testing.assert_array_equal(
        with_mailbox.counters.tests + with_mailbox.counters.mailbox_skips, without.counters.tests
    )
    assert with_mailbox.counters.mailbox_skips.sum() > 0
    hit = with_mailbox.hit
    assert (with_mailbox.counters.nodes[hit] >= 1).all()
    assert (with_mailbox.counters.tests[hit] >= 1).all()


def test_exact_insertion_stores_fewer_references(small_dragon):
    bbox = ra.build(small_dragon, "grid", density=20).stats()
    exact = ra.build(small_dragon, "grid", density=20, insert="exact").stats()
    assert exact["references"] < bbox["references"]
    assert exact["avg_intersections_per_ray"] <= bbox["avg_intersections_per_ray"]


def test_grid_stats_follow_the_design(spheres):
    stats = ra.build(spheres, "grid").stats()
    for key in ("build_seconds", "nodes", "leaves", "nonempty_leaves", "max_depth", "references",
                "avg_prims_per_nonempty_leaf", "bytes", "expected_traversal_steps", "expected_leaves_visited",
                "expected_intersections", "expected_cost", "avg_nodes_per_ray", "avg_intersections_per_ray"):
        assert key in stats
    assert abs(stats["nodes"] - 8 * len(spheres)) < 0.2 * 8 * len(spheres)
    assert stats["references"] >= len(spheres)
    assert 0 < stats["nonempty_leaves"] <= stats["leaves"]


def test_cost_model_resolution_matches_the_formula(spheres):
    from rayaccel.structures.grid.calibrate import cost_ratio

    grid = ra.build(spheres, "grid", resolution="cost")
    expected = 2 * len(spheres) * cost_ratio(spheres.kind)
    assert 0.6 * expected < grid.stats()["nodes"] < 1.6 * expected


@settings(max_examples=examples(25), deadline=None)
@given(
    n=st.integers(1, 60),
    seed=st.integers(0, 2**16),
    density=st.floats(0.1, 30.0),
    exact=st.booleans(),
)
def test_random_scenes_property(n, seed, density, exact):
    scene = ra.random_spheres(n, seed=seed, fill=0.2)
    origins, directions = random_rays(scene, 300, seed=seed)
    reference = ra.build(scene, "none").intersect(origins, directions)
    grid = ra.build(scene, "grid", density=density, insert="exact" if exact else "bbox")
    assert_same_hits(reference, grid.intersect(origins, directions))


def test_mailbox_stamps_start_again_when_they_run_out(small_dragon):
    """The int32 stamps start again from 0 when a call would pass MAX_STAMP, and the mailbox an
    earlier call stamped (0 to n - 1, as the new call's) is cleared before it is lent again:
    the call after the wrap tests and skips exactly what a fresh structure does."""
    origins, directions = camera_rays(small_dragon, 32)
    grid = ra.build(small_dragon, "grid", density=20)
    first = grid.intersect(origins, directions, counters=True)
    assert first.counters.mailbox_skips.sum() > 0
    grid.mailboxes._next_stamp = MAX_STAMP - len(origins) // 2
    wrapped = grid.intersect(origins, directions, counters=True)
    assert grid.mailboxes._next_stamp == len(origins)
    assert_same_hits(wrapped, first)
    np.testing.assert_array_equal(wrapped.counters.tests, first.counters.tests)
    np.testing.assert_array_equal(wrapped.counters.mailbox_skips, first.counters.mailbox_skips)
    with pytest.raises(ValueError, match="split the batch"), MailboxPool(10).lend(MAX_STAMP + 1):
        pass
