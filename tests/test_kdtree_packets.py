"""Packets of eight rays through the kd-tree's binary walk (``width=2``; the default eight-wide walk
is the BVH's, :mod:`test_packets`) give each ray the hit brute force gives it."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from conftest import (
    assert_same_hits,
    axis_parallel_rays,
    camera_rays,
    one_eye_vertex_and_edge_rays,
    random_rays,
    vertex_and_edge_rays,
)
from test_packets import shadow_rays

import rayaccel as ra
from rayaccel.ray_order import MIN_PACKET_RAYS, lane_packets_pay, packets_pay
from rayaccel.rays import prepare_rays
from rayaccel.structures.kdtree import accelerator
from rayaccel.structures.kdtree.layout import CHILD_SHIFT, plane_bracket
from rayaccel.structures.kdtree.traverse import cross_split, plane_steps
from rayaccel.structures.kdtree.traverse_packet import PACKET, PACKET_ROWS, _split_lanes


@pytest.fixture
def every_batch_in_packets(monkeypatch):
    """Incoherent batches too, so that packets of mixed directions (walked ray by ray), rays
    through vertices and edges and axis-parallel rays take the packet kernel."""
    monkeypatch.setattr(accelerator, "packets_pay", lambda batch, lo, hi, sampled: True)


def brute_packets_single(scene):
    return (ra.build(scene, "none"), ra.build(scene, "kdtree", width=2),
            ra.build(scene, "kdtree", width=2, packets=False))


def assert_all_queries_match(brute, accels, origins, directions, t_min=0.0, t_max=np.inf):
    reference = brute.intersect(origins, directions, t_min, t_max)
    for accel in accels:
        assert_same_hits(reference, accel.intersect(origins, directions, t_min, t_max))
        np.testing.assert_array_equal(accel.occluded(origins, directions, t_min, t_max), reference.hit)
        np.testing.assert_array_equal(accel.intersect(origins, directions, t_min, t_max, any_hit=True).hit,
                                      reference.hit)
    return reference


@pytest.mark.parametrize("extra", range(8))
def test_camera_packets_of_every_fill_match_brute_force(small_dragon, extra):
    """A camera's rays take the packets without asking; batches of every length modulo the
    packet size end in a partial packet."""
    origins, directions = camera_rays(small_dragon, 40)
    origins, directions = origins[:MIN_PACKET_RAYS + extra], directions[:MIN_PACKET_RAYS + extra]
    b = small_dragon.bounds()
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    brute, packets, _ = brute_packets_single(small_dragon)
    assert_all_queries_match(brute, [packets], origins, directions)


@pytest.mark.parametrize("skip_empty", [True, False])
def test_packets_entering_empty_leaves_or_not_match_brute_force(small_dragon, every_batch_in_packets, skip_empty):
    """Packets that skip the empty children of a node (the default) and packets that enter them
    give the answers of brute force, for camera and random rays alike."""
    brute = ra.build(small_dragon, "none")
    packets = ra.build(small_dragon, "kdtree", width=2, skip_empty=skip_empty)
    assert packets.options["skip_empty"] == skip_empty
    for origins, directions in (camera_rays(small_dragon, 40), random_rays(small_dragon, 2000, seed=11)):
        assert_all_queries_match(brute, [packets], origins, directions)


@pytest.mark.parametrize("limits", ["shared", "per ray"])
def test_wide_camera_packets_with_limits_match_brute_force(small_dragon, limits):
    """A wide camera, so that packets hold rays that miss the tree's box beside rays that hit
    the model, each ray with its own interval when asked."""
    b = small_dragon.bounds()
    origins, directions = ra.Camera.framing(b.scene_lo, b.scene_hi, fov=70.0).rays(101, 101)
    t_min, t_max = 0.0, np.inf
    if limits == "per ray":
        rng = np.random.default_rng(3)
        t_min = rng.uniform(0.0, 0.5, len(origins))
        t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, rng.uniform(0.6, 1.2, len(origins)))
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    reference = assert_all_queries_match(ra.build(small_dragon, "none"),
                                         [ra.build(small_dragon, "kdtree", width=2), ra.build(small_dragon, "kdtree")],
                                         origins, directions, t_min, t_max)
    assert reference.hit.any() and not reference.hit.all()


@pytest.mark.parametrize("extra", [0, 3, 7])
def test_shadow_packets_match_brute_force(small_dragon, extra):
    """Shadow rays from neighbouring hits to one light, which start apart: each lane keeps its
    own interval in every cell."""
    origins, directions = shadow_rays(small_dragon, 160)
    origins, directions = origins[:MIN_PACKET_RAYS + extra], directions[:MIN_PACKET_RAYS + extra]
    b = small_dragon.bounds()
    assert lane_packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    brute, packets, single = brute_packets_single(small_dragon)
    for t_min, t_max in ((1e-6, 1.0), (0.0, np.inf)):
        reference = assert_all_queries_match(brute, [packets, single], origins, directions, t_min, t_max)
        assert reference.hit.any() and not reference.hit.all()


@pytest.mark.parametrize("rays", ["random", "vertices_and_edges", "axis_parallel"])
def test_packets_of_any_rays_match_brute_force(small_dragon, every_batch_in_packets, rays):
    """Packets whose rays point every way (walked ray by ray where their signs differ), aimed
    exactly at vertices and edges, or along the axes with zero components of either sign
    (rays lying in split planes), each with its own interval."""
    make = {"random": random_rays, "vertices_and_edges": vertex_and_edge_rays, "axis_parallel": axis_parallel_rays}
    origins, directions = make[rays](small_dragon, 4099, seed=3)
    rng = np.random.default_rng(5)
    t_min = rng.choice([0.0, 0.2, 0.5], len(origins))
    t_max = np.where(rng.random(len(origins)) < 0.5, np.inf, t_min + rng.uniform(0.0, 2.0, len(origins)))
    brute, packets, single = brute_packets_single(small_dragon)
    assert_all_queries_match(brute, [packets, single], origins, directions, t_min, t_max)


def test_packets_of_one_origin_through_vertices_and_edges_match_brute_force(small_dragon):
    """Camera-like rays from one far point aimed exactly at vertices and edge midpoints, sorted
    by direction so that most packets share their signs: a ray through an edge or a vertex
    must hit exactly the triangles brute force hits."""
    origins, directions = one_eye_vertex_and_edge_rays(small_dragon, 3000, (0.3, 0.2, 4.0))
    b = small_dragon.bounds()
    rng = np.random.default_rng(5)
    assert packets_pay(prepare_rays(origins, directions), b.scene_lo, b.scene_hi)
    brute, packets, _ = brute_packets_single(small_dragon)
    assert_all_queries_match(brute, [packets], origins, directions)
    assert_all_queries_match(brute, [packets], origins, directions, 0.5, rng.uniform(0.99, 1.01, len(directions)))


def test_sphere_packets_match_brute_force(spheres):
    origins, directions = camera_rays(spheres, 48)
    assert_all_queries_match(ra.build(spheres, "none"),
                             [ra.build(spheres, "kdtree", width=2), ra.build(spheres, "kdtree")], origins, directions,
                             0.0, 3.0)


def test_packets_option(small_dragon):
    assert ra.build(small_dragon, "kdtree").options["packets"] is True
    with pytest.raises(TypeError, match="packets"):
        ra.build(small_dragon, "kdtree", packets="yes")


@numba.njit(cache=False)
def _split_by_lane_and_alone(state, axis, node_records, slot, alone):
    """The vector split of all lanes, and the single walk's split of each lane alone at the plane
    of ``node_records[0]``, read flat as the walks read them."""
    words = node_records.reshape(-1)
    planes = words.view(np.float32)
    for r in range(PACKET):
        o, inv = state[axis * PACKET + r], state[(3 + axis) * PACKET + r]
        t0, t1 = state[6 * PACKET + r], state[7 * PACKET + r]
        exit_step, entry_step = plane_steps(inv)
        nxt, near_t1, pushed, push_t0, push_t1 = cross_split(planes[0], words[1], o, inv, exit_step, entry_step, t0, t1)
        alone[r, 0], alone[r, 1], alone[r, 2], alone[r, 3], alone[r, 4] = nxt, near_t1, pushed, push_t0, push_t1
    return _split_lanes(state, axis, np.float64(planes[0]), slot)


def test_vector_split_is_the_single_walks_split_in_each_lane():
    """:func:`_split_lanes` makes, lane by lane, the single walk's choice
    (:func:`.traverse.cross_split`) to the bit: which sides each lane reaches and its
    intervals there, for planes before, inside, after and at the ends of the lanes' intervals (the
    ray leaving or entering the plane's bracket right there)."""
    rng = np.random.default_rng(11)
    checked = 0
    for trial in range(400):
        axis = int(rng.integers(0, 3))
        positive = bool(rng.integers(0, 2))
        state = np.zeros(PACKET_ROWS * PACKET)
        origin = rng.uniform(-1.0, 1.0, PACKET)
        direction = rng.uniform(0.1, 1.0, PACKET) * (1.0 if positive else -1.0)
        inv = 1.0 / direction
        state[axis * PACKET:(axis + 1) * PACKET] = origin
        state[(3 + axis) * PACKET:(4 + axis) * PACKET] = inv
        t0 = rng.uniform(0.0, 1.0, PACKET)
        t1 = t0 + rng.choice([0.0, 0.5, 2.0], PACKET)
        lane = int(rng.integers(0, PACKET))
        split = np.float32(rng.uniform(-3.0, 3.0))
        at_plane = (rng.choice(plane_bracket(split)) - origin[lane]) * inv[lane]
        end = rng.integers(0, 3)
        if end == 1:
            t0[lane], t1[lane] = at_plane, max(t1[lane], at_plane)
        elif end == 2:
            t0[lane], t1[lane] = min(t0[lane], at_plane), at_plane
        state[6 * PACKET:7 * PACKET], state[7 * PACKET:8 * PACKET] = t0, t1
        slot = np.zeros(2 * PACKET)
        alone = np.zeros((PACKET, 5))
        node_records = np.array([[0, 1 << CHILD_SHIFT | axis]], dtype=np.int32)
        node_records.view(np.float32)[0, 0] = split
        after = state.copy()
        sides = _split_by_lane_and_alone(after, axis, node_records, slot, alone)
        near, far = (1, 2) if positive else (2, 1)
        for r in range(PACKET):
            goes_near = bool(sides >> r & 1)
            goes_far = bool(sides >> (PACKET + r) & 1)
            nxt, near_t1, pushed, push_t0, push_t1 = alone[r]
            assert goes_near == (nxt == near), (trial, r)
            assert goes_far == (nxt == far or pushed == far), (trial, r)
            if goes_near and goes_far:
                assert after[7 * PACKET + r] == near_t1 and slot[r] == push_t0 and slot[PACKET + r] == push_t1
            elif goes_near:
                assert after[7 * PACKET + r] == t1[r]
            else:
                assert slot[r] == t0[r] and slot[PACKET + r] == t1[r]
            checked += 1
    assert checked == 400 * PACKET
