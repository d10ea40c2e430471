"""Packets of eight rays through the eight-wide BVH give each ray the hit brute force gives it."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from conftest import (
    assert_counts_and_lists_match,
    assert_same_hits,
    axis_parallel_rays,
    bound_whole_span,
    camera_rays,
    one_eye_vertex_and_edge_rays,
    random_rays,
    vertex_and_edge_rays,
)

import rayaccel as ra
from rayaccel.geometry.gather import corner
from rayaccel.geometry.primitive import ray_setup
from rayaccel.geometry.triangle import intersect_triangle
from rayaccel.ray_order import MIN_PACKET_RAYS, lane_packets_pay, packets_pay
from rayaccel.ray_tiles import image_row_length
from rayaccel.rays import prepare_rays, ray_limit
from rayaccel.structures.actions import is_closer
from rayaccel.structures.bvh import accelerator, traverse_packet
from rayaccel.structures.bvh.lane_slab import (
    LANE_SLAB_ROWS,
    bound_lane_slab,
    bound_lane_slabs,
    enter_children_by_lane,
    enter_children_of_lanes,
    set_up_lane_slab,
    set_up_lane_slabs,
)
from rayaccel.structures.bvh.packet_slab import BOUND_VALUES, PACKET, PACKET_ROWS, load_lane_limits
from rayaccel.structures.bvh.packet_triangle import (
    HIT_ROW,
    NOT_SHARED,
    SHEAR_ROW,
    SHEAR_ROWS,
    hits_by_lane,
    set_up_shear,
)
from rayaccel.structures.bvh.traverse_packet import LANE_ROWS, SPAN, _keep_closer_hits
from rayaccel.structures.bvh.wide import WIDTH
from rayaccel.structures.bvh.wide_slab import enter_children, slab_limits, slab_ray


@pytest.fixture(params=["shared origin", "by lane"])
def every_batch_in_packets(monkeypatch, request):
    """Incoherent batches too, so that packets of mixed directions, rays through vertices and
    edges and axis-parallel rays walk each packet kernel: the one whose box test bounds the
    packet as a whole and the one that tests its rays lane by lane."""
    by_lane = request.param == "by lane"
    monkeypatch.setattr(accelerator, "packets_pay", lambda batch, lo, hi, sampled: not by_lane)
    monkeypatch.setattr(accelerator, "lane_packets_pay", lambda batch, lo, hi, sampled: by_lane)


def brute_and_packets(scene):
    return ra.build(scene, "none"), ra.build(scene, "bvh-binned"), ra.build(scene, "bvh-binned", packets=False)


@pytest.mark.parametrize("extra", range(8))
def test_camera_packets_of_every_fill_match_brute_force(small_dragon, extra):
    """A pinhole camera's rays are traced in packets without asking; batches of every length
    modulo the packet size end in a partial packet."""
    origins, directions = camera_rays(small_dragon, 40)
    origins, directions = origins[:MIN_PACKET_RAYS + extra], directions[:MIN_PACKET_RAYS + extra]
    b = small_dragon.bounds()
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    brute, packets = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    assert_same_hits(brute.intersect(origins, directions), packets.intersect(origins, directions))
    np.testing.assert_array_equal(packets.occluded(origins, directions), brute.occluded(origins, directions))


@pytest.mark.parametrize("side", [64, 61], ids=["tiles", "rows"])
def test_packet_answers_are_the_single_walks_in_every_field(small_dragon, side):
    """A full packet writes its answers four rows a store: every field of a closest hit (NaN
    barycentrics and -1 for ``geom`` on a miss) and every any-hit flag are the single walk's, for
    an image's rays in tiles and rows that do not tile."""
    b = small_dragon.bounds()
    origins, directions = ra.Camera.framing(b.scene_lo, b.scene_hi).rays(side, side)
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    assert (image_row_length(directions, SPAN // 2) > 0) == (side == 64)
    packets, single = ra.build(small_dragon, "bvh-binned"), ra.build(small_dragon, "bvh-binned", packets=False)
    hits, expected = packets.intersect(origins, directions), single.intersect(origins, directions)
    assert 0.1 < (expected.prim >= 0).mean() < 0.9
    for field in ("t", "prim", "u", "v", "geom"):
        np.testing.assert_array_equal(getattr(hits, field), getattr(expected, field))
    np.testing.assert_array_equal(packets.occluded(origins, directions), single.occluded(origins, directions))


def spans_missing_the_box(origins, directions, lo, hi):
    """How many whole runs of :data:`SPAN` consecutive rays each miss the box ``[lo, hi]``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        near, far = (lo - origins) / directions, (hi - origins) / directions
    enter = np.nanmax(np.minimum(near, far), axis=1)
    leave = np.nanmin(np.maximum(near, far), axis=1)
    misses = (enter > leave) | (leave < 0.0)
    whole = len(misses) // SPAN * SPAN
    return int(misses[:whole].reshape(-1, SPAN).all(axis=1).sum())


@pytest.mark.parametrize("limits", ["shared", "per ray"])
def test_camera_spans_that_miss_the_scene_match_brute_force(small_dragon, limits):
    """A wide camera whose image the model fills only in part: whole runs of rays miss the root's
    boxes and are answered as misses without being loaded as packets; the runs around the model
    and the partial run at the end walk as before. Per-ray limits bound a run by their extremes."""
    b = small_dragon.bounds()
    origins, directions = ra.Camera.framing(b.scene_lo, b.scene_hi, fov=70.0).rays(101, 101)
    assert spans_missing_the_box(origins, directions, b.scene_lo, b.scene_hi) >= 10
    t_min, t_max = 0.0, np.inf
    if limits == "per ray":
        rng = np.random.default_rng(3)
        t_min = rng.uniform(0.0, 0.5, len(origins))
        t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, rng.uniform(0.6, 1.2, len(origins)))
    brute, packets = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    assert_same_hits(brute.intersect(origins, directions, t_min, t_max),
                     packets.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(packets.occluded(origins, directions, t_min, t_max),
                                  brute.occluded(origins, directions, t_min, t_max))
    assert_counts_and_lists_match(brute, packets, origins, directions)


def test_camera_rays_with_a_patch_left_out_match_brute_force(small_dragon, monkeypatch):
    """A wide camera's rays that miss the model's box and those that meet it, each batch without
    the others: no longer an image (:func:`rayaccel.ray_tiles.image_row_length`), they go in packets
    of consecutive rays, and a packet that straddles the patch left out (the end of one row and the
    start of the next beside it) is walked ray by ray (:func:`.traverse_packet._lanes_jump`); the
    same hits as brute force, closest, any hit, counts and lists."""
    b = small_dragon.bounds()
    origins, directions = ra.Camera.framing(b.scene_lo, b.scene_hi, fov=70.0).rays(128, 96)
    with np.errstate(divide="ignore", invalid="ignore"):
        near, far = (b.scene_lo - origins) / directions, (b.scene_hi - origins) / directions
    meets = np.nanmax(np.minimum(near, far), axis=1) <= np.nanmin(np.maximum(near, far), axis=1)
    straddles = []
    jumps = traverse_packet._lanes_jump
    walks = []
    walk_rays = accelerator.walk_rays
    monkeypatch.setattr(accelerator, "walk_rays", lambda walk, *args, **options: walks.append(walk.__name__)
                        or walk_rays(walk, *args, **options))
    for part in (~meets, meets):
        o, d = np.ascontiguousarray(origins[part]), np.ascontiguousarray(directions[part])
        assert image_row_length(d) == 0 and packets_pay(prepare_rays(o, d), b.scene_lo, b.scene_hi)
        straddles.append(sum(jumps(d, first, first + 4) for first in range(0, len(d) - 7, 8)))
        walks.clear()
        brute, packets = ra.build(small_dragon, "none"), ra.build(small_dragon, "bvh-binned")
        assert_same_hits(brute.intersect(o, d), packets.intersect(o, d))
        np.testing.assert_array_equal(packets.occluded(o, d), brute.occluded(o, d))
        assert walks == ["wide_packet_kernel"] * 2
        assert_counts_and_lists_match(brute, packets, o, d)
    assert all(count > 10 for count in straddles)
    row = directions[:8]
    assert not jumps(row, 0, 4) and not jumps(directions, 0, 128)
    assert jumps(np.vstack((directions[124:128], directions[128:132])), 0, 4)


def shadow_rays(scene, side):
    """Rays from the hits of a camera's rays toward a point light above the scene, the light at
    ``t = 1``, as a renderer casts them."""
    origins, directions = camera_rays(scene, side)
    hits = ra.build(scene, "bvh-binned").intersect(origins, directions)
    points = origins[hits.hit] + hits.t[hits.hit, None] * directions[hits.hit]
    b = scene.bounds()
    light = 0.5 * (b.scene_lo + b.scene_hi) + np.array([0.3, 2.0, 0.5]) * (b.scene_hi - b.scene_lo)
    return points, light - points


@pytest.mark.parametrize("extra", range(8))
def test_shadow_rays_in_packets_of_every_fill_match_brute_force(small_dragon, extra):
    """Shadow rays from neighbouring hits to one light are traced in packets tested lane by lane
    without asking; batches of every length modulo the packet size end in a partial packet."""
    origins, directions = shadow_rays(small_dragon, 160)
    origins, directions = origins[:MIN_PACKET_RAYS + extra], directions[:MIN_PACKET_RAYS + extra]
    b = small_dragon.bounds()
    batch = prepare_rays(origins, directions)
    assert lane_packets_pay(batch, b.scene_lo, b.scene_hi) and not packets_pay(batch, b.scene_lo, b.scene_hi)
    brute, packets, single = brute_and_packets(small_dragon)
    for t_min, t_max in ((1e-6, 1.0), (0.0, np.inf)):
        reference = brute.intersect(origins, directions, t_min, t_max)
        assert reference.hit.any() and not reference.hit.all()
        assert_same_hits(reference, packets.intersect(origins, directions, t_min, t_max))
        np.testing.assert_array_equal(packets.occluded(origins, directions, t_min, t_max), reference.hit)
        np.testing.assert_array_equal(single.occluded(origins, directions, t_min, t_max), reference.hit)


def test_incoherent_batches_are_not_packed(small_dragon):
    b = small_dragon.bounds()
    for rays in (random_rays(small_dragon, 5000), camera_rays(small_dragon, 16)):
        batch = prepare_rays(*rays)
        assert not packets_pay(batch, b.scene_lo, b.scene_hi)
        assert not lane_packets_pay(batch, b.scene_lo, b.scene_hi)


@pytest.mark.parametrize("rays", ["random", "vertices_and_edges", "axis_parallel"])
def test_packets_of_any_rays_match_brute_force(small_dragon, every_batch_in_packets, rays):
    """Packets whose rays point every way (split into packets of one where an axis has both
    signs), aimed exactly at vertices and edges, or along the axes with zero components of
    either sign, with each ray's own interval."""
    make = {"random": random_rays, "vertices_and_edges": vertex_and_edge_rays, "axis_parallel": axis_parallel_rays}
    origins, directions = make[rays](small_dragon, 4099, seed=3)
    rng = np.random.default_rng(5)
    t_min = rng.choice([0.0, 0.2, 0.5], len(origins))
    t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, t_min + rng.uniform(0.0, 2.0, len(origins)))
    brute, packets, single = brute_and_packets(small_dragon)
    reference = brute.intersect(origins, directions, t_min, t_max)
    assert_same_hits(reference, packets.intersect(origins, directions, t_min, t_max))
    assert_same_hits(reference, single.intersect(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(packets.occluded(origins, directions, t_min, t_max), reference.hit)
    np.testing.assert_array_equal(packets.intersect(origins, directions, t_min, t_max, any_hit=True).hit,
                                  reference.hit)


def test_packets_of_one_origin_through_vertices_and_edges_match_brute_force(small_dragon, every_batch_in_packets):
    """Rays from one point far out along +z, aimed exactly at vertices and edge midpoints and
    sorted by direction, so that a packet's rays share the triangle test's axes and a camera
    packet tests each triangle on all its rays at once; the rays through an edge or a vertex
    must hit exactly the triangles brute force hits, with or without limits."""
    origins, directions = one_eye_vertex_and_edge_rays(small_dragon, 3000, (0.0, 0.0, 4.0))
    rng = np.random.default_rng(5)
    brute, packets, _ = brute_and_packets(small_dragon)
    assert_same_hits(brute.intersect(origins, directions), packets.intersect(origins, directions))
    t_max = rng.uniform(0.99, 1.01, len(directions))
    assert_same_hits(brute.intersect(origins, directions, 0.5, t_max),
                     packets.intersect(origins, directions, 0.5, t_max))
    np.testing.assert_array_equal(packets.occluded(origins, directions), brute.occluded(origins, directions))


def test_sphere_packets_match_brute_force(spheres, every_batch_in_packets):
    origins, directions = camera_rays(spheres, 48)
    brute, packets, _ = brute_and_packets(spheres)
    assert_same_hits(brute.intersect(origins, directions), packets.intersect(origins, directions))
    np.testing.assert_array_equal(packets.occluded(origins, directions, 0.0, 3.0),
                                  brute.occluded(origins, directions, 0.0, 3.0))


def test_packets_option(small_dragon):
    assert ra.build(small_dragon, "bvh-binned").options["packets"] is True
    with pytest.raises(TypeError, match="packets"):
        ra.build(small_dragon, "bvh-binned", packets="yes")


@pytest.mark.parametrize("rays", ["camera", "random"])
def test_packets_count_and_list_what_brute_force_does(small_dragon, every_batch_in_packets, rays):
    """Counting and listing (all hits and the nearest few) in packets."""
    origins, directions = camera_rays(small_dragon, 33) if rays == "camera" else random_rays(small_dragon, 1500, 9)
    brute, packets, _ = brute_and_packets(small_dragon)
    assert_counts_and_lists_match(brute, packets, origins, directions)


@pytest.mark.parametrize("query", ["intersect", "occluded"])
@pytest.mark.parametrize("defect, words", [
    ("NaN origin", "origins has 1 row"),
    ("infinite direction", "directions has 1 row"),
    ("zero direction", "1 ray direction"),
])
@pytest.mark.parametrize("batch, kernel", [
    ("random", "wide_nearest_kernel"),
    ("camera", "wide_packet_kernel"),
    ("shadow", "lane_packet_kernel"),
    ("random interleaved", "interleaved_nearest_kernel"),
])
def test_walks_that_check_their_rays_refuse_unusable_ones(small_dragon, monkeypatch, query, defect, words, batch,
                                                          kernel):
    """The eight-wide walks read the rays of ``intersect`` and ``occluded`` unchecked and test each
    themselves: one bad ray among many, in each walk, raises the error the check up front raises,
    naming its index."""
    origins, directions = {"random": lambda: random_rays(small_dragon, 1500),
                           "camera": lambda: camera_rays(small_dragon, 40),
                           "shadow": lambda: shadow_rays(small_dragon, 160),
                           "random interleaved": lambda: random_rays(small_dragon, 1500)}[batch]()
    origins, directions = origins[:1500].copy(), directions[:1500].copy()
    if batch == "random":
        origins, directions = origins[:MIN_PACKET_RAYS - 1], directions[:MIN_PACKET_RAYS - 1]
    if batch == "random interleaved":
        monkeypatch.setattr(accelerator, "interleaving_pays", lambda batch, lo, hi, nbytes, sampled, **_: True)
    walks = []
    walk_rays = accelerator.walk_rays
    monkeypatch.setattr(accelerator, "walk_rays", lambda walk, *args, **options: walks.append(walk.__name__) or
                        walk_rays(walk, *args, **options))
    bvh = ra.build(small_dragon, "bvh-binned")
    getattr(bvh, query)(origins, directions)
    assert walks == [kernel]
    bad = len(origins) // 2 + 3
    if defect == "NaN origin":
        origins[bad, 1] = np.nan
    elif defect == "infinite direction":
        directions[bad, 2] = -np.inf
    else:
        directions[bad] = 0.0
    with pytest.raises(ValueError, match=f"{words}.*first at index {bad}"):
        getattr(bvh, query)(origins, directions)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_span_bounds_stand_for_the_rays_check_only_when_every_ray_is_usable(dtype):
    """The packet walk skips its check of a span's rays when :func:`.packet_slab.bound_span` returns
    0: then the bounds are the span's, and a NaN or infinite coordinate anywhere in it gives 2
    instead, a zero direction component (an all-zero direction among them) 1."""
    rng = np.random.default_rng(5)
    signs = np.array([1.0, -1.0, 1.0])
    origins = rng.uniform(-3.0, 3.0, (SPAN, 3)).astype(dtype)
    directions = (rng.uniform(0.1, 1.0, (SPAN, 3)) * signs).astype(dtype)
    bounds = np.zeros(BOUND_VALUES)
    assert bound_whole_span(origins, directions, bounds) == 0
    for axis in range(3):
        positive = signs[axis] > 0
        o, d = origins[:, axis].astype(float), directions[:, axis].astype(float)
        assert bounds[5 * axis:5 * axis + 5].tolist() == [
            axis if positive else axis + 3, o.max() if positive else o.min(), o.min() if positive else o.max(),
            1.0 / d.max(), 1.0 / d.min()]
    for row in (0, 7, SPAN // 2 - 1, SPAN // 2, SPAN - 1):
        for array in (origins, directions):
            for axis in range(3):
                for bad in (np.nan, np.inf, -np.inf):
                    kept = array[row, axis]
                    array[row, axis] = bad
                    assert bound_whole_span(origins, directions, bounds) == 2, (row, axis, bad)
                    array[row, axis] = kept
        kept = directions[row].copy()
        for zeroed in ([0], [1, 2], [0, 1, 2]):
            directions[row, zeroed] = 0.0
            assert bound_whole_span(origins, directions, bounds) == 1, (row, zeroed)
            directions[row, 1] = np.nan
            assert bound_whole_span(origins, directions, bounds) == 2, (row, zeroed)
            directions[row] = kept


@numba.njit
def _lane_test(records, node, slabs, scales, lanes, entry):
    """The lane test called from Python. Not cached: Numba's cache checks only this file's time
    stamp, so a cached wrapper kept the old lane test compiled in after ``packet_slab`` changed
    (a mutation of the lane test passed)."""
    return enter_children_by_lane(records, node, slabs, scales, lanes, entry)


@numba.njit(error_model="numpy")
def _set_up_lanes(origins, directions, t_max, reach, slabs, scales):
    """Each ray's lane of ``slabs`` and ``scales``, one ray at a time, as the lane packet walk sets
    up a partial packet."""
    for r in range(PACKET):
        set_up_lane_slab(slabs, scales, r, origins[r, 0], origins[r, 1], origins[r, 2], directions[r, 0],
                         directions[r, 1], directions[r, 2], 1.0 / directions[r, 0], 1.0 / directions[r, 1],
                         1.0 / directions[r, 2], reach[0], reach[1], reach[2])
        bound_lane_slab(slabs, scales, r, 0.0, t_max[r])


@numba.njit
def _set_up_lanes_at_once(origins, directions, second, state, reach, slabs, scales):
    """The packet of rows 0-3 and ``second`` to ``second + 3`` set up in vector lanes."""
    set_up_lane_slabs(origins, directions, 0, second, state, slabs, scales, reach[0], reach[1], reach[2])


@pytest.mark.parametrize("second", [4, 9])
def test_lane_slabs_in_vector_lanes_are_those_of_the_rays_one_by_one(second):
    """A full packet's slabs set up in vector lanes are, to the bit, those of its rays set up one at a
    time, rays beyond the float32 test's range (which enter every box) included: zero and tiny
    direction components, huge and subnormal ones, origins far out."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        origins = rng.normal(size=(second + 4, 3)) * 10.0 ** rng.integers(-3, 4, size=(second + 4, 1))
        directions = rng.normal(size=(second + 4, 3))
        lanes = np.r_[0:4, second:second + 4]
        special = rng.integers(0, 7, size=8)
        for lane, kind in zip(lanes, special):
            axis = rng.integers(0, 3)
            if kind == 1:
                directions[lane, axis] = 0.0
            elif kind == 2:
                directions[lane, axis] = 1e-310
            elif kind == 3:
                directions[lane] *= 1e280
            elif kind == 4:
                origins[lane, axis] = 1e35
            elif kind == 5:
                directions[lane, axis] = -0.0
        reach = np.abs(rng.normal(size=3)) * 10.0 ** rng.integers(-2, 3)
        state = np.zeros(LANE_ROWS * PACKET)
        with np.errstate(divide="ignore", over="ignore"):
            state[3 * PACKET:6 * PACKET] = (1.0 / directions[lanes]).T.ravel()
        at_once = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32), np.zeros(2 * PACKET)
        _set_up_lanes_at_once(origins, directions, second, state, reach, *at_once)
        one_by_one = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32), np.zeros(2 * PACKET)
        _set_up_lanes(np.ascontiguousarray(origins[lanes]), np.ascontiguousarray(directions[lanes]),
                      np.zeros(PACKET), reach, *one_by_one)
        rows = 9 * PACKET
        assert np.array_equal(at_once[0][:rows].view(np.uint32), one_by_one[0][:rows].view(np.uint32)), trial
        assert np.array_equal(at_once[1].view(np.uint64), one_by_one[1].view(np.uint64)), trial


@numba.njit
def _bound_lanes(t_min, t_max, lanes, slabs, scales):
    """Each lane's interval in ``slabs``, one ray at a time, from the batch's limits of the rays
    ``lanes`` (:func:`rayaccel.rays.ray_limit`: one value for all when the arrays hold one)."""
    for r in range(PACKET):
        bound_lane_slab(slabs, scales, r, ray_limit(t_min, lanes[r]), ray_limit(t_max, lanes[r]))


@numba.njit
def _bound_lanes_at_once(t_min, t_max, second, state, slabs, scales):
    """The limits of the packet of rows 0-3 and ``second`` to ``second + 3`` loaded and bounded in
    vector lanes."""
    load_lane_limits(t_min, t_max, 0, second, state)
    bound_lane_slabs(slabs, scales, state)


@pytest.mark.parametrize("shared", [False, True], ids=["per ray", "one for all"])
@pytest.mark.parametrize("second", [4, 9])
def test_lane_limits_in_vector_lanes_are_those_of_the_rays_one_by_one(second, shared):
    """A full packet's limits loaded and bounded in vector lanes are, to the bit, those of its rays
    bounded one at a time: per-ray or shared ``t_min`` and ``t_max``, zero, subnormal, huge and
    infinite ends, on directions scaled by powers of two far from 1."""
    rng = np.random.default_rng(5)
    n = second + 4
    lanes = np.r_[0:4, second:second + 4]
    for trial in range(40):
        size = 1 if shared else n
        t_min = np.abs(rng.normal(size=size)) * 10.0 ** rng.integers(-300, 4, size=size)
        t_max = t_min + np.abs(rng.normal(size=size)) * 10.0 ** rng.integers(-3, 300, size=size)
        t_min[rng.random(size) < 0.2] = 0.0
        t_max[rng.random(size) < 0.2] = np.inf
        unscale = 2.0 ** rng.integers(-60, 60, size=PACKET).astype(float)
        at_once = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32), np.r_[1.0 / unscale, unscale]
        state = np.zeros(LANE_ROWS * PACKET)
        _bound_lanes_at_once(t_min, t_max, second, state, *at_once)
        one_by_one = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32), at_once[1].copy()
        _bound_lanes(t_min, t_max, lanes, *one_by_one)
        assert np.array_equal(at_once[0].view(np.uint32), one_by_one[0].view(np.uint32)), trial
        expected = np.broadcast_to(np.c_[t_min, t_max][lanes if not shared else [0] * PACKET].T, (2, PACKET))
        assert np.array_equal(state[6 * PACKET:8 * PACKET], expected.ravel()), trial


@numba.njit
def _single_test(records, node, origin, direction, t_max, reach, entry):
    """The single-ray walk's test of one ray against wide ``node``'s children, and the scale of
    its entry distances."""
    ix, iy, iz = 1.0 / direction[0], 1.0 / direction[1], 1.0 / direction[2]
    slab = slab_ray(origin[0], origin[1], origin[2], direction[0], direction[1], direction[2], ix, iy, iz, reach[0],
                    reach[1], reach[2])
    enter_from, exit_by = slab_limits(slab, 0.0, t_max)
    entered = enter_children(records, node, 0 if ix >= 0.0 else 3, 1 if iy >= 0.0 else 4, 2 if iz >= 0.0 else 5,
                             slab, enter_from, exit_by, entry)
    return entered, slab[9]


def test_lane_test_answers_each_lane_of_the_mask_as_alone(small_dragon):
    """The lane-by-lane box test skips the lanes outside its mask: for any mask it gives each lane
    of the mask the children that the single-ray walk's test gives that ray, nothing for the
    others, and the nearest entry of the lanes in the mask along their rays. Some rays end
    before the boxes they aim at."""
    accel = ra.build(small_dragon, "bvh-binned")
    rng = np.random.default_rng(7)
    origins, _ = random_rays(small_dragon, PACKET, seed=7)
    corners = small_dragon.vertices[small_dragon.faces[rng.integers(0, len(small_dragon.faces), PACKET)]]
    directions = corners.mean(axis=1) - origins
    t_max = np.where(np.arange(PACKET) % 3 == 0, 0.5, np.inf)
    reach = np.maximum(np.abs(accel.root_record[0, :3]), np.abs(accel.root_record[0, 3:6])).astype(np.float64)
    slabs = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32)
    scales = np.zeros(2 * PACKET)
    _set_up_lanes(origins, directions, t_max, reach, slabs, scales)
    entry = np.empty(WIDTH)
    single_entry = np.empty(WIDTH, np.float32)
    tested = 0
    for node in range(len(accel.wide)):
        if _lane_test(accel.wide, node, slabs, scales, 0xFF, entry) == 0:
            continue
        alone, alone_entry = [], []
        for lane in range(PACKET):
            alone.append((_lane_test(accel.wide, node, slabs, scales, 1 << lane, entry) >> (8 * lane)) & 0xFF)
            alone_entry.append(entry.copy())
            entered, scale = _single_test(accel.wide, node, origins[lane], directions[lane], t_max[lane], reach,
                                          single_entry)
            assert alone[lane] == entered
            expected = np.where([entered >> c & 1 for c in range(WIDTH)], single_entry.astype(np.float64) * scale,
                                np.inf)
            assert np.array_equal(alone_entry[lane], expected)
        for lanes in rng.integers(0, 256, 24):
            word = _lane_test(accel.wide, node, slabs, scales, int(lanes), entry)
            in_mask = [lane for lane in range(PACKET) if lanes >> lane & 1]
            assert word % (1 << 64) == sum(alone[lane] << (8 * lane) for lane in in_mask)
            nearest = np.min([np.full(WIDTH, np.inf)] + [alone_entry[lane] for lane in in_mask], axis=0)
            assert np.array_equal(entry, nearest)
        tested += 1
    assert tested >= 16


@numba.njit(cache=False)
def _child_test(records, node, slabs, scales, lanes, entry, read_entries, near_x, near_y, near_z):
    """The test of each child against the packet's lanes at once, called from Python (not cached,
    as :func:`_lane_test`)."""
    return enter_children_of_lanes(records, node, slabs, scales, lanes, entry, read_entries, near_x, near_y, near_z)


@pytest.mark.parametrize("scales_differ", [False, True], ids=["one scale", "scales differ"])
def test_child_test_sends_each_lane_where_the_lane_test_does(small_dragon, scales_differ):
    """Testing each child against all the packet's rays at once (rays that point to one side along
    each axis) gives, for any mask of lanes, byte ``c`` the lanes that the lane-by-lane test sends
    into child ``c``, and bit ``c`` of the children some lane enters; its entry distances are the
    lane test's where the rays share their scale and no greater where they do not, and ``-inf``
    when the walk does not read them. Some rays end before the boxes they aim at."""
    accel = ra.build(small_dragon, "bvh-binned")
    rng = np.random.default_rng(11)
    origins, _ = random_rays(small_dragon, PACKET, seed=11)
    lo, hi = small_dragon.vertices.min(axis=0), small_dragon.vertices.max(axis=0)
    directions = hi + 2.0 * (hi - lo) - origins
    directions /= np.abs(directions).max(axis=1, keepdims=True)
    if scales_differ:
        directions[::2] *= 8.0
    t_max = np.where(np.arange(PACKET) % 3 == 0, 0.5, np.inf)
    reach = np.maximum(np.abs(accel.root_record[0, :3]), np.abs(accel.root_record[0, 3:6])).astype(np.float64)
    slabs = np.zeros(LANE_SLAB_ROWS * PACKET, np.float32)
    scales = np.zeros(2 * PACKET)
    _set_up_lanes(origins, directions, t_max, reach, slabs, scales)
    assert (len(set(scales[:PACKET])) > 1) == scales_differ
    near = [axis if directions[0, axis] >= 0.0 else axis + 3 for axis in range(3)]
    lane_entry, child_entry = np.empty(WIDTH), np.empty(WIDTH)
    tested = 0
    for node in range(len(accel.wide)):
        for lanes in [0xFF, *rng.integers(1, 256, 8)]:
            word = _lane_test(accel.wide, node, slabs, scales, int(lanes), lane_entry) % (1 << 64)
            children, by_child = _child_test(accel.wide, node, slabs, scales, int(lanes), child_entry, True, *near)
            expected = [sum(((word >> (8 * lane + c)) & 1) << lane for lane in range(PACKET)) for c in range(WIDTH)]
            assert by_child % (1 << 64) == sum(rays << (8 * c) for c, rays in enumerate(expected))
            assert children == sum(1 << c for c, rays in enumerate(expected) if rays)
            if scales_differ:
                assert np.all(child_entry <= lane_entry)
            else:
                assert np.array_equal(child_entry, lane_entry)
            _child_test(accel.wide, node, slabs, scales, int(lanes), child_entry, False, *near)
            assert np.all(child_entry == -np.inf)
            tested += children != 0
    assert tested >= 16


@numba.njit(cache=False)
def _lanes_and_single_tests(triangles, origins, directions, t_min, t_max, state, lanes_hits, single_hits):
    """For each triangle, the packet's vector test and the single-ray test of each lane: the
    lanes each reports hit and their ``(t, u, v)``, or -1 where the lanes' axes differ."""
    shared = True
    kx0, ky0, kz0 = 0, 0, 0
    for r in range(PACKET):
        _, _, _, _, _, _, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_setup(
            origins[r, 0], origins[r, 1], origins[r, 2], directions[r, 0], directions[r, 1], directions[r, 2])
        if r == 0:
            kx0, ky0, kz0 = kx, ky, kz
        shared &= kx == kx0 and ky == ky0 and kz == kz0
        for k, value in enumerate((sx, sy, okx, oky, okz, sz)):
            state[(SHEAR_ROW + k) * PACKET + r] = value
        state[(PACKET_ROWS - 2) * PACKET + r] = t_min[r]
        state[(PACKET_ROWS - 1) * PACKET + r] = t_max[r]
    if not shared:
        return -1
    for k in range(triangles.shape[0]):
        word = hits_by_lane(state, 0xFF, corner(triangles, k, 0, kx0), corner(triangles, k, 0, ky0),
                            corner(triangles, k, 0, kz0), corner(triangles, k, 1, kx0), corner(triangles, k, 1, ky0),
                            corner(triangles, k, 1, kz0), corner(triangles, k, 2, kx0), corner(triangles, k, 2, ky0),
                            corner(triangles, k, 2, kz0))
        for r in range(PACKET):
            if word >> r & 1:
                for j in range(3):
                    lanes_hits[k, r, j] = state[(HIT_ROW + j) * PACKET + r]
            t, u, v = intersect_triangle(triangles, k, state[(SHEAR_ROW + 2) * PACKET + r],
                                         state[(SHEAR_ROW + 3) * PACKET + r], state[(SHEAR_ROW + 4) * PACKET + r],
                                         kx0, ky0, kz0, state[SHEAR_ROW * PACKET + r],
                                         state[(SHEAR_ROW + 1) * PACKET + r], state[(SHEAR_ROW + 5) * PACKET + r],
                                         t_min[r], t_max[r])
            if t != np.inf:
                single_hits[k, r, 0], single_hits[k, r, 1], single_hits[k, r, 2] = t, u, v
    return 0


def test_vector_triangle_test_is_the_single_ray_test_in_each_lane():
    """The packets' triangle test (:func:`.packet_triangle.hits_by_lane`) gives each lane the hit,
    distance and barycentrics the single-ray test gives its ray, to the bit: on triangles hit
    through their vertices and edges, on degenerate ones (a repeated corner, collinear corners,
    all three corners alike) and with limits that cut hits off."""
    rng = np.random.default_rng(11)
    compared = hits = 0
    for _ in range(300):
        corners = rng.normal(size=(24, 3, 3))
        corners[:4, 2] = corners[:4, 0]
        corners[4:8, 2] = 0.5 * (corners[4:8, 0] + corners[4:8, 1])
        corners[8:10] = corners[8:10, :1]
        triangles = corners.reshape(-1, 9)
        eye = rng.normal(size=3) + np.array([0.0, 0.0, 6.0])
        targets = corners[rng.integers(0, 24, PACKET)]
        weights = rng.choice([0.0, 0.5, 1.0, 1.0 / 3.0], size=(PACKET, 3))
        weights /= np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
        weights[weights.sum(axis=1) == 0] = 1.0 / 3.0
        aims = np.einsum("rj,rjk->rk", weights, targets)
        origins = eye + 1e-3 * rng.normal(size=(PACKET, 3))
        directions = aims - origins
        t_min = rng.choice([0.0, 0.5, 1.0], PACKET)
        t_max = rng.choice([np.inf, 1.0, 0.9999999999999999, 2.0], PACKET)
        lanes_hits = np.full((len(triangles), PACKET, 3), np.nan)
        single_hits = np.full((len(triangles), PACKET, 3), np.nan)
        state = np.zeros(LANE_ROWS * PACKET)
        if _lanes_and_single_tests(triangles, origins, directions, t_min, t_max, state, lanes_hits, single_hits) < 0:
            continue
        np.testing.assert_array_equal(lanes_hits, single_hits)
        compared += 1
        hits += int(np.isfinite(single_hits[..., 0]).sum())
    assert compared >= 250 and hits >= 1000


@numba.njit(cache=False)
def _shear_set_ups(origins, directions, state, scalar_rows):
    """The vector set-up of the packet's triangle-test constants, and the scalar one of each
    ray in ``scalar_rows`` (rows as :data:`.packet_triangle.SHEAR_ROW` orders them); returns
    the vector set-up's code and the scalar axes' code, or ``NOT_SHARED`` where they differ."""
    code = set_up_shear(origins, directions, 0, PACKET // 2, state)
    scalar_code = 0
    for r in range(PACKET):
        _, _, _, _, _, _, kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_setup(
            np.float64(origins[r, 0]), np.float64(origins[r, 1]), np.float64(origins[r, 2]),
            np.float64(directions[r, 0]), np.float64(directions[r, 1]), np.float64(directions[r, 2]))
        for k, value in enumerate((sx, sy, okx, oky, okz, sz)):
            scalar_rows[k, r] = value
        lane_code = kx + 4 * ky + 16 * kz
        if r == 0:
            scalar_code = lane_code
        elif lane_code != scalar_code:
            scalar_code = NOT_SHARED
    return code, scalar_code


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_vector_shear_set_up_is_each_rays_own(dtype):
    """The packets' set-up of the triangle test (:func:`.packet_triangle.set_up_shear`) gives
    each lane the constants the single-ray set-up gives its ray, to the bit, and reports shared
    axes exactly when every ray has the same: on directions of either sign along each axis, some
    with two components of equal size (the dominant axis then decided by the ties' order)."""
    rng = np.random.default_rng(13)
    kinds = set()
    for _ in range(400):
        directions = rng.normal(size=(PACKET, 3)) * rng.choice([1.0, 1e-3, 1e3], size=(1, 3))
        ties = rng.integers(0, 4)
        if ties:
            directions[:, ties % 3] = directions[:, (ties + 1) % 3] * rng.choice([1.0, -1.0], size=PACKET)
        if rng.random() < 0.5:
            directions[:] = directions[0] * rng.uniform(0.5, 2.0, size=(PACKET, 1))
        origins = rng.normal(size=(PACKET, 3)).astype(dtype)
        directions = directions.astype(dtype)
        state = np.zeros(LANE_ROWS * PACKET)
        scalar_rows = np.zeros((SHEAR_ROWS, PACKET))
        code, scalar_code = _shear_set_ups(origins, directions, state, scalar_rows)
        assert code == scalar_code
        if code != NOT_SHARED:
            np.testing.assert_array_equal(state[SHEAR_ROW * PACKET:(SHEAR_ROW + SHEAR_ROWS) * PACKET],
                                          scalar_rows.ravel())
        kinds.add(code)
    assert NOT_SHARED in kinds and len(kinds) >= 7


@numba.njit(cache=False)
def _keep(state, best_prim, hit, prim):
    """The vector keeping of a triangle's hits, called from Python (not cached, as :func:`_lane_test`)."""
    return _keep_closer_hits(state, best_prim, hit, prim)


def test_vector_keeping_of_hits_is_each_lanes_own():
    """A packet's lanes keep a triangle's hits as :func:`rayaccel.structures.actions.is_closer` decides
    lane by lane: a nearer hit, or an equal distance on a lower primitive, or any hit of a lane with
    none yet, but not an infinite distance nor a lane outside the hit mask; the best distance,
    barycentrics and primitive change together, and the mask returned names the lanes that changed."""
    rng = np.random.default_rng(5)
    best_row, hit_row = 7 * PACKET, HIT_ROW * PACKET
    for _ in range(200):
        state = rng.choice([0.5, 1.0, 2.0, np.inf], size=LANE_ROWS * PACKET)
        best_prim = rng.choice([-1, 3, 7, 12], size=PACKET).astype(np.int64)
        hit, prim = int(rng.integers(0, 256)), int(rng.choice([3, 7, 12]))
        expected_state, expected_prim = state.copy(), best_prim.copy()
        changed = 0
        for r in range(PACKET):
            t = state[hit_row + r]
            if hit >> r & 1 and is_closer(t, prim, state[best_row + r], best_prim[r]):
                for j in range(3):
                    expected_state[best_row + j * PACKET + r] = state[hit_row + j * PACKET + r]
                expected_prim[r] = prim
                changed |= 1 << r
        assert _keep(state, best_prim, hit, prim) == changed
        np.testing.assert_array_equal(state, expected_state)
        np.testing.assert_array_equal(best_prim, expected_prim)
