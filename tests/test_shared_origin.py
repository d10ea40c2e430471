"""Rays from one origin, given once: the same answers as the origin copied to every ray."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (
    assert_counts_and_lists_match,
    assert_same_hits,
    bound_whole_span,
    camera_rays,
    one_eye_vertex_and_edge_rays,
)

import rayaccel as ra
from rayaccel.ray_order import MIN_PACKET_RAYS
from rayaccel.rays import prepare_rays
from rayaccel.structures.bvh import accelerator
from rayaccel.structures.bvh.packet_slab import BOUND_VALUES, PACKET
from rayaccel.structures.bvh.traverse_packet import SPAN

ONE_ORIGIN_FORMS = {
    "one row": lambda origins: origins[:1].copy(),
    "three numbers": lambda origins: origins[0].copy(),
    "broadcast": lambda origins: np.broadcast_to(origins[0], origins.shape),
}


@pytest.fixture
def walked(monkeypatch):
    """The walks the eight-wide BVH runs, each with the shape of the origins it was given."""
    walks = []
    walk_rays = accelerator.walk_rays

    def recording(walk, n_rays, root_record, records, links, prim_order, kind, geometry, origins, *args, **options):
        walks.append((walk.__name__, origins.shape))
        return walk_rays(walk, n_rays, root_record, records, links, prim_order, kind, geometry, origins, *args,
                         **options)

    monkeypatch.setattr(accelerator, "walk_rays", recording)
    return walks


def per_ray_limits(rng, n):
    """``(t_min, t_max)`` per ray: ``t_min`` in [0, 0.3], ``t_max`` infinite or in [0.5, 1.5]."""
    return rng.uniform(0.0, 0.3, n), np.where(rng.random(n) < 0.5, np.inf, rng.uniform(0.5, 1.5, n))


def assert_as_brute_force_and_the_copy(brute, accel, hits, one, origins, directions, limits):
    """``hits``, ``accel``'s answer to the rays from the one origin ``one`` within ``limits``, are
    brute force's, and bit for bit (counters too, when asked for) those of the origin copied to
    every ray; so is ``occluded``."""
    assert_same_hits(brute.intersect(origins, directions, *limits), hits)
    copied = accel.intersect(np.ascontiguousarray(origins), directions, *limits, counters=hits.counters is not None)
    for field in ("t", "prim", "u", "v", "geom"):
        np.testing.assert_array_equal(getattr(hits, field), getattr(copied, field))
    if hits.counters is not None:
        for field in hits.counters._fields:
            np.testing.assert_array_equal(getattr(hits.counters, field), getattr(copied.counters, field))
    np.testing.assert_array_equal(accel.occluded(one, directions, *limits),
                                  brute.occluded(origins, directions, *limits))


@pytest.mark.parametrize("form", ONE_ORIGIN_FORMS)
def test_one_origin_stays_one_only_where_asked(form):
    eye_view, directions = camera_rays(ra.TriangleMesh(np.eye(3), [[0, 1, 2]]), 8)
    assert eye_view.strides[0] == 0 and prepare_rays(eye_view, directions, shared_origin=True).shares_origin
    origins = eye_view.copy()
    one = ONE_ORIGIN_FORMS[form](origins)
    kept = prepare_rays(one, directions, shared_origin=True)
    assert kept.origins.shape == (3,) and kept.size == len(directions) and kept.shares_origin
    np.testing.assert_array_equal(kept.with_origin_per_ray().origins, origins)
    copied = prepare_rays(one, directions)
    assert copied.origins.shape == origins.shape and not copied.shares_origin
    np.testing.assert_array_equal(copied.origins, origins)
    assert prepare_rays(origins, directions, shared_origin=True).origins.shape == origins.shape
    with pytest.raises(ValueError, match="same shape"):
        prepare_rays(origins[:2], directions, shared_origin=True)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("n", [0, 1, 2, 3, 5, 1000, 4099])
def test_one_origin_copied_to_every_ray(dtype, n):
    directions = np.random.default_rng(n).normal(size=(n, 3)).astype(dtype)
    eye = np.array([0.25, -1.5, 3.0], dtype=dtype)
    for one in (eye, eye[None], np.broadcast_to(eye, directions.shape)):
        copied = prepare_rays(one, directions, check=False, keep_float32=True).with_origin_per_ray()
        assert copied.origins.dtype == dtype and copied.origins.flags.c_contiguous
        np.testing.assert_array_equal(copied.origins, np.tile(eye, (n, 1)))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("form", ONE_ORIGIN_FORMS)
@pytest.mark.parametrize("side", [40, 64], ids=["rays in a row", "image tiles"])
def test_camera_rays_from_one_origin_match_brute_force_and_their_copies(small_dragon, walked, dtype, form, side):
    """A camera's rays given one origin walk the interval packets with that origin alone (as image
    tiles when the rows are a tile's width apart), to the same bits as its copy per ray; a batch
    ending in a partial span and a partial packet, and per-ray limits, included."""
    b = small_dragon.bounds()
    origins, directions = ra.Camera.framing(b.scene_lo, b.scene_hi).rays(side, side)
    n = len(directions) - 2 * SPAN - 3
    origins, directions = origins[:n].astype(dtype), directions[:n].astype(dtype)
    one = ONE_ORIGIN_FORMS[form](origins)
    brute, bvh = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    for limits in ((0.0, np.inf), per_ray_limits(np.random.default_rng(4), n)):
        walked.clear()
        hits = bvh.intersect(one, directions, *limits)
        assert walked == [("wide_packet_kernel", (3,))]
        assert_as_brute_force_and_the_copy(brute, bvh, hits, one, origins, directions, limits)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("method", ["kdtree", "grid-bvh"])
def test_kdtree_and_grid_bvh_take_one_origin(small_dragon, walked, method, dtype):
    """The kd-tree's cells, walked eight-wide in the BVH's packets, and the grid-BVH's walk, which
    reads its rays through ``ray_at``, take a camera's one origin as it is: the same bits as its
    copy per ray, and brute force's hits, per-ray limits included."""
    origins, directions = (array.astype(dtype) for array in camera_rays(small_dragon, 48))
    brute, accel = ra.build(small_dragon, "none"), ra.build(small_dragon, method)
    assert accel._prepare_rays(origins[0], directions, 0.0, np.inf).shares_origin
    for limits in ((0.0, np.inf), per_ray_limits(np.random.default_rng(6), len(directions))):
        walked.clear()
        hits = accel.intersect(origins[0], directions, *limits)
        assert walked == ([("wide_packet_kernel", (3,))] if method == "kdtree" else [])
        assert_as_brute_force_and_the_copy(brute, accel, hits, origins[0], origins, directions, limits)


@pytest.mark.parametrize("n", [1, PACKET - 1, MIN_PACKET_RAYS - 1])
def test_small_batches_from_one_origin_walk_with_a_copy(small_dragon, walked, n):
    origins, directions = camera_rays(small_dragon, 40)
    brute, bvh = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    assert_same_hits(brute.intersect(origins[:n], directions[:n]), bvh.intersect(origins[0], directions[:n]))
    assert all(shape == (n, 3) for _, shape in walked)


def test_rays_from_one_origin_heading_apart_walk_with_a_copy(small_dragon, walked):
    """Rays from one point in random directions are no camera: the single-ray walk takes them, each
    with the origin copied to its row."""
    b = small_dragon.bounds()
    eye = 0.5 * (b.scene_lo + b.scene_hi)
    directions = np.random.default_rng(2).normal(size=(3000, 3))
    brute, bvh = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    assert_same_hits(brute.intersect(eye[None], directions), bvh.intersect(eye, directions))
    np.testing.assert_array_equal(bvh.occluded(eye, directions, 0.0, 0.05), brute.occluded(eye, directions, 0.0, 0.05))
    assert [name for name, _ in walked] == ["wide_nearest_kernel"] * 2
    assert all(shape == (3000, 3) for _, shape in walked)


@pytest.mark.parametrize("by_lane", [False, True], ids=["interval packets", "lane packets"])
def test_one_origin_through_vertices_and_edges_matches_brute_force(small_dragon, monkeypatch, walked, by_lane):
    """Rays from one eye aimed exactly at vertices and edge midpoints, given the eye once, in
    the interval packets and (forced) in the lane packets, which take the origin copied."""
    monkeypatch.setattr(accelerator, "packets_pay", lambda batch, lo, hi, sampled: not by_lane)
    monkeypatch.setattr(accelerator, "lane_packets_pay", lambda batch, lo, hi, sampled: by_lane)
    origins, directions = one_eye_vertex_and_edge_rays(small_dragon, 3000, (0.0, 0.0, 4.0))
    brute, bvh = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    assert_same_hits(brute.intersect(origins, directions), bvh.intersect(origins[0], directions))
    np.testing.assert_array_equal(bvh.occluded(origins[0], directions), brute.occluded(origins, directions))
    assert walked[0][1] == ((3000, 3) if by_lane else (3,))


@pytest.mark.parametrize("scene_name", ["dragon", "spheres"])
@pytest.mark.parametrize("method, options", [("grid", {}), ("hgrid", {}), ("bvh-binned", {"width": 2}),
                                             ("bvh-binned", {"bounds": "kdop"})])
def test_walks_reading_rays_through_ray_at_take_one_origin(small_dragon, scene_name, method, options):
    """The walks of the uniform and hierarchical grids and the binary BVH read their rays through
    ``ray_at`` and take a camera's one origin as it is: the same bits and counters as its copy per
    ray, brute force's hits, per-ray limits included; a NaN origin refused."""
    rng = np.random.default_rng(7)
    scene = small_dragon if scene_name == "dragon" else ra.Spheres(rng.uniform(-1, 1, (300, 3)),
                                                                    rng.uniform(0.01, 0.1, 300))
    origins, directions = camera_rays(scene, 40)
    brute, accel = ra.build(scene, "none"), ra.build(scene, method, **options)
    assert accel._prepare_rays(origins[0], directions, 0.0, np.inf).shares_origin
    for limits in ((0.0, np.inf), per_ray_limits(rng, len(directions))):
        hits = accel.intersect(origins[0], directions, *limits, counters=True)
        assert_as_brute_force_and_the_copy(brute, accel, hits, origins[0], origins, directions, limits)
    with pytest.raises(ValueError, match="NaN"):
        accel.intersect(np.array([0.0, np.nan, 0.0]), directions)


def test_other_structures_and_queries_take_one_origin(small_dragon):
    origins, directions = camera_rays(small_dragon, 33)
    brute = ra.build(small_dragon, "none")
    for method in ("kdtree", "grid", "bvh-sah"):
        assert_same_hits(brute.intersect(origins, directions), ra.build(small_dragon, method).intersect(origins[0],
                                                                                                        directions))
    bvh = ra.build(small_dragon, "bvh-binned")
    np.testing.assert_array_equal(bvh.count(origins[0], directions), brute.count(origins, directions))
    assert_counts_and_lists_match(brute, bvh, origins, directions)


@pytest.mark.parametrize("query", ["intersect", "occluded"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_an_unusable_shared_origin_is_refused(small_dragon, query, bad):
    origins, directions = camera_rays(small_dragon, 40)
    eye = origins[0].copy()
    eye[1] = bad
    with pytest.raises(ValueError, match=r"origins has 1 row\(s\) with NaN or infinite coordinates \(first at index 0"):
        getattr(ra.build(small_dragon, "bvh-binned"), query)(eye, directions)


@pytest.mark.parametrize("query", ["intersect", "occluded"])
@pytest.mark.parametrize("row", [5, SPAN + 7, 1599])
def test_a_zero_direction_among_rays_from_one_origin_is_refused(small_dragon, query, row):
    origins, directions = camera_rays(small_dragon, 40)
    directions[row] = 0.0
    with pytest.raises(ValueError, match=f"1 ray direction.*first at index {row}"):
        getattr(ra.build(small_dragon, "bvh-binned"), query)(origins[0], directions)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_span_bounds_of_one_origin_are_those_of_its_copies(dtype):
    rng = np.random.default_rng(8)
    eye = rng.uniform(-3.0, 3.0, 3).astype(dtype)
    directions = (rng.uniform(0.1, 1.0, (SPAN, 3)) * [1.0, -1.0, -1.0]).astype(dtype)
    shared, copied = np.zeros(BOUND_VALUES), np.zeros(BOUND_VALUES)
    assert bound_whole_span(eye, directions, shared) == 0
    assert bound_whole_span(np.ascontiguousarray(np.broadcast_to(eye, directions.shape)), directions, copied) == 0
    np.testing.assert_array_equal(shared[:15], copied[:15])
    for axis in range(3):
        for bad in (np.nan, np.inf):
            unusable = eye.copy()
            unusable[axis] = bad
            assert bound_whole_span(unusable, directions, shared) == 2
