"""Float32 rays: the eight-wide BVH walks read them as they are and answer exactly what they answer
for the rays' float64 copy; every other structure takes their float64 copy."""

from __future__ import annotations

from contextlib import ExitStack
from unittest.mock import patch

import numpy as np
import pytest
from conftest import assert_same_hits, axis_parallel_rays, camera_rays, examples, random_rays, vertex_and_edge_rays
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_packets import shadow_rays
from test_properties import triangle_scene_rays, triangle_scenes

import rayaccel as ra
from rayaccel.ray_order import MIN_PACKET_RAYS
from rayaccel.structures.bvh import accelerator

WALKS = {
    "random": "wide_nearest_kernel",
    "vertices_and_edges": "wide_nearest_kernel",
    "axis_parallel": "wide_nearest_kernel",
    "camera": "wide_packet_kernel",
    "shadow": "lane_packet_kernel",
    "random interleaved": "interleaved_nearest_kernel",
}


def rays_of(scene, batch):
    origins, directions = {
        "random": lambda: random_rays(scene, MIN_PACKET_RAYS - 1),
        "vertices_and_edges": lambda: vertex_and_edge_rays(scene, MIN_PACKET_RAYS - 1),
        "axis_parallel": lambda: axis_parallel_rays(scene, MIN_PACKET_RAYS - 1),
        "camera": lambda: camera_rays(scene, 41),
        "shadow": lambda: shadow_rays(scene, 130),
        "random interleaved": lambda: random_rays(scene, 1500),
    }[batch]()
    return origins.astype(np.float32), directions.astype(np.float32)


def own_limits(n, seed=2):
    rng = np.random.default_rng(seed)
    t_min = rng.choice([0.0, 0.1, 0.4], n)
    t_max = np.where(rng.random(n) < 0.5, np.inf, t_min + rng.uniform(0.0, 1.5, n))
    return t_min, t_max


@pytest.mark.parametrize("method", ["bvh-binned", "kdtree"])
@pytest.mark.parametrize("limits", ["shared", "per ray"])
@pytest.mark.parametrize("batch", list(WALKS))
def test_float32_rays_walk_as_they_are_and_hit_what_their_float64_copy_hits(small_dragon, monkeypatch, batch,
                                                                             limits, method):
    """Closest hit, any hit and ``occluded`` of float32 rays in each eight-wide walk (single ray,
    interval packets with partial packets, lane packets, interleaved), over a BVH and over a
    kd-tree's cells: the walk receives the float32 arrays, and every field of the answer is bit
    for bit that of the float64 copy, which brute force confirms."""
    origins, directions = rays_of(small_dragon, batch)
    if batch == "random interleaved":
        monkeypatch.setattr(accelerator, "interleaving_pays", lambda batch, lo, hi, nbytes, sampled, **_: True)
    seen = []
    walk_rays = accelerator.walk_rays
    monkeypatch.setattr(accelerator, "walk_rays", lambda walk, n, *args, **options: seen.append((walk.__name__, args))
                        or walk_rays(walk, n, *args, **options))
    t_min, t_max = (0.0, np.inf) if limits == "shared" else own_limits(len(origins))
    wide, brute = ra.build(small_dragon, method), ra.build(small_dragon, "none")
    wide_origins, wide_directions = origins.astype(np.float64), directions.astype(np.float64)
    for any_hit in (False, True):
        seen.clear()
        hits = wide.intersect(origins, directions, t_min, t_max, any_hit=any_hit)
        assert seen[0][0] == WALKS[batch]
        ray_arrays = [arg for arg in seen[0][1] if isinstance(arg, np.ndarray) and arg.shape == origins.shape]
        assert len(ray_arrays) == 2 and all(array.dtype == np.float32 for array in ray_arrays)
        reference = wide.intersect(wide_origins, wide_directions, t_min, t_max, any_hit=any_hit)
        for field in ("t", "prim", "u", "v", "geom"):
            np.testing.assert_array_equal(getattr(hits, field), getattr(reference, field))
        if not any_hit:
            assert_same_hits(brute.intersect(wide_origins, wide_directions, t_min, t_max), hits)
    np.testing.assert_array_equal(wide.occluded(origins, directions, t_min, t_max),
                                  brute.occluded(wide_origins, wide_directions, t_min, t_max))


@pytest.mark.parametrize("method", ["kdtree", "grid", "bvh-sah"])
def test_float32_rays_of_other_walks_take_their_float64_copy(small_dragon, method):
    """Structures whose walks read float64 rays only (and the BVH and the kd-tree walked two-wide) answer
    float32 rays as their float64 copy."""
    origins, directions = rays_of(small_dragon, "camera")
    options = {"width": 2} if method in ("bvh-sah", "kdtree") else {}
    structure = ra.build(small_dragon, method, **options)
    assert not structure._walk_takes_float32
    assert_same_hits(structure.intersect(origins.astype(np.float64), directions.astype(np.float64)),
                     structure.intersect(origins, directions))


def test_mixed_float_types_are_traced_in_float64(small_dragon):
    """Float32 origins with float64 directions (or the reverse) take the float64 walk."""
    origins, directions = rays_of(small_dragon, "camera")
    wide = ra.build(small_dragon, "bvh-binned")
    reference = wide.intersect(origins.astype(np.float64), directions.astype(np.float64))
    assert_same_hits(reference, wide.intersect(origins, directions.astype(np.float64)))
    assert_same_hits(reference, wide.intersect(origins.astype(np.float64), directions))


@pytest.mark.parametrize("query", ["intersect", "occluded"])
@pytest.mark.parametrize("batch", ["random", "camera", "shadow"])
def test_unusable_float32_rays_are_refused_by_index(small_dragon, query, batch):
    """A NaN or infinite float32 coordinate, or a zero float32 direction, raises the error a
    float64 one raises, naming the first bad ray."""
    origins, directions = rays_of(small_dragon, batch)
    wide = ra.build(small_dragon, "bvh-binned")
    bad = len(origins) // 2 + 1
    for defect, words in (("nan", "NaN or infinite"), ("inf", "NaN or infinite"), ("zero", "1 ray direction")):
        o, d = origins.copy(), directions.copy()
        if defect == "nan":
            o[bad, 0] = np.nan
        elif defect == "inf":
            d[bad, 1] = np.inf
        else:
            d[bad] = 0.0
        with pytest.raises(ValueError, match=f"{words}.*first at index {bad}"):
            getattr(wide, query)(o, d)


FORCED_WALKS = {
    "single": {"packets_pay": False, "lane_packets_pay": False, "interleaving_pays": False},
    "interval packets": {"packets_pay": True, "lane_packets_pay": False, "interleaving_pays": False},
    "lane packets": {"packets_pay": False, "lane_packets_pay": True, "interleaving_pays": False},
    "interleaved": {"packets_pay": False, "lane_packets_pay": False, "interleaving_pays": True},
}


@settings(max_examples=examples(25), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), walk=st.sampled_from(list(FORCED_WALKS)))
def test_generated_scenes_and_float32_rays_match_their_float64_copy(data, walk):
    """Generated lattice scenes (degenerate, duplicated and axis-aligned triangles, scales from
    1e-20 to 1e20) and float32 rays through their vertices and edges, along lattice and random
    directions, repeated into batches of packets, walked by each eight-wide walk: closest hit and
    ``occluded`` as for the rays' float64 copy, bit for bit, and brute force's."""
    mesh, to_world, lattice, faces = data.draw(triangle_scenes())
    origins, directions = triangle_scene_rays(data.draw, lattice, faces, 24)
    world_origins = to_world(origins).astype(np.float32)
    world_directions = (to_world(directions) - to_world(np.zeros(3))).astype(np.float32)
    usable = np.isfinite(world_origins).all(axis=1) & np.isfinite(world_directions).all(axis=1) & \
        (np.abs(world_directions).sum(axis=1) > 0)
    repeats = -(-(MIN_PACKET_RAYS + 5) // max(int(usable.sum()), 1))
    origins32 = np.tile(world_origins[usable], (repeats, 1))
    directions32 = np.tile(world_directions[usable], (repeats, 1))
    origins64, directions64 = origins32.astype(np.float64), directions32.astype(np.float64)
    wide, brute = ra.build(mesh, "bvh-binned"), ra.build(mesh, "none")
    with ExitStack() as stack:
        for name, value in FORCED_WALKS[walk].items():
            stack.enter_context(patch.object(accelerator, name, lambda *args, value=value, **_: value))
        hits = wide.intersect(origins32, directions32)
        reference = wide.intersect(origins64, directions64)
        occluded = wide.occluded(origins32, directions32)
    for field in ("t", "prim", "u", "v", "geom"):
        np.testing.assert_array_equal(getattr(hits, field), getattr(reference, field))
    assert_same_hits(brute.intersect(origins64, directions64), hits)
    np.testing.assert_array_equal(occluded, reference.prim >= 0)
