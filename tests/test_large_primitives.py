"""The scene's large primitives: any-hit queries settled by them before the walk, and the kd-tree built
without them, every query of which visits them first; against brute force."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import GROUND, assert_same_hits, camera_rays, ground_and_clutter

import rayaccel as ra
from rayaccel.geometry.gather import is_lanes
from rayaccel.structures.actions import hit_flags
from rayaccel.structures.kdtree import accelerator as kd_accelerator
from rayaccel.structures.large_primitives import LARGE_SHARE, MAX_LARGE, SAMPLED_RAYS, large_primitives, unsettled_rays

SETTLING = [m for m in ra.methods() if ra.build_class(m)._large_primitives_first is True] + ["kdtree"]
KD_IN = {"large_apart": False}
"""The kd-tree with its large primitives in its leaves, whose any-hit queries test them first."""


def build(scene, method):
    """The structure whose any-hit queries settle rays by the large primitives first."""
    return ra.build(scene, method, **(KD_IN if method == "kdtree" else {}))


def rays_meeting_the_ground(n, seed=0):
    """Origins over the ground, half the directions downward; some rays start on the ground, some go
    straight down through its diagonal and corners, and ``t_min``, ``t_max`` differ per ray (some
    intervals empty, some ending before the ground)."""
    rng = np.random.default_rng(seed)
    origins = rng.uniform([0, 0, 0], [GROUND, 3.5, GROUND], size=(n, 3))
    directions = rng.normal(size=(n, 3))
    origins[: n // 10, 1] = 0.0
    diagonal = slice(n // 10, n // 5)
    along = rng.uniform(0, GROUND, n // 5 - n // 10)
    origins[diagonal] = np.column_stack([along, np.full_like(along, 2.0), along])
    directions[diagonal] = [0.0, -1.0, 0.0]
    origins[n // 5: n // 5 + 4] = [[0, 1, 0], [GROUND, 1, 0], [GROUND, 1, GROUND], [0, 1, GROUND]]
    directions[n // 5: n // 5 + 4] = [0.0, -1.0, 0.0]
    t_min = rng.choice([0.0, 0.0, 0.0, 0.5, 2.0], n)
    t_max = np.where(rng.random(n) < 0.1, rng.uniform(0, 1.5, n), np.inf)
    return origins, directions, t_min, t_max


def test_the_ground_is_large_and_no_triangle_of_a_scan_is(bunny):
    forest = ra.load_scene("forest-small-chair")
    large = ra.build(forest, "kdtree")._large_primitives
    assert sorted(large.prims) == [0, 1]
    assert (forest.vertices[forest.faces[large.prims]][..., 1] == 0).all()
    np.testing.assert_array_equal(large.geom, forest.vertices[forest.faces[large.prims]].reshape(-1, 9))
    b = bunny.bounds()
    assert len(large_primitives(bunny, b.scene_lo, b.scene_hi).prims) == 0


def test_at_most_the_largest_few_are_taken():
    rng = np.random.default_rng(1)
    n = MAX_LARGE + 5
    sizes = rng.permutation(np.linspace(1.0, 2.0, n))
    corners = np.zeros((n, 3, 3))
    corners[:, 1, 0] = sizes
    corners[:, 2, 2] = sizes
    mesh = ra.TriangleMesh(corners.reshape(-1, 3), np.arange(3 * n).reshape(-1, 3))
    large = large_primitives(mesh, np.zeros(3), np.array([2.0, 1e-9, 2.0]))
    np.testing.assert_array_equal(large.prims, np.argsort(-sizes)[:MAX_LARGE])
    sphere_box = np.array([10.0, 10.0, 10.0])
    spheres = ra.Spheres([[1, 1, 1], [5, 5, 5], [9, 9, 9]], [0.5, 4.0, np.sqrt(1.01 * LARGE_SHARE * 600 / (4 * np.pi))])
    assert list(large_primitives(spheres, np.zeros(3), sphere_box).prims) == [1, 2]


@pytest.mark.parametrize("method", SETTLING)
def test_settled_any_hit_queries_agree_with_brute_force(method):
    scene = ground_and_clutter()
    reference, accel = ra.build(scene, "none"), build(scene, method)
    origins, directions, t_min, t_max = rays_meeting_the_ground(3000)
    expected = reference.occluded(origins, directions, t_min, t_max)
    prepared = accel._prepare_rays(origins, directions, t_min, t_max)
    walked = unsettled_rays(accel._large_primitives, scene.kind, prepared, hit_flags(expected.copy()))
    assert len(walked.origins) < len(origins)
    for rays in ((origins, directions), (origins.astype(np.float32), directions.astype(np.float32))):
        np.testing.assert_array_equal(accel.occluded(*rays, t_min, t_max), reference.occluded(*rays, t_min, t_max))
    np.testing.assert_array_equal(accel.occluded(origins, directions, 0.0, 4.0),
                                  reference.occluded(origins, directions, 0.0, 4.0))
    hits = accel.intersect(origins, directions, t_min, t_max, any_hit=True)
    np.testing.assert_array_equal(hits.prim >= 0, expected)
    np.testing.assert_array_equal(hits.geom, np.where(expected, 0, -1))
    hit = np.flatnonzero(expected)
    assert ((hits.t[hit] >= t_min[hit]) & (hits.t[hit] <= t_max[hit])).all()
    for prim in np.unique(hits.prim[hit]):
        rows = hit[hits.prim[hit] == prim]
        alone = ra.build(ra.TriangleMesh(scene.vertices, scene.faces[[prim]]), "none")
        found = alone.intersect(origins[rows], directions[rows], t_min[rows], t_max[rows])
        np.testing.assert_array_equal(found.prim, 0)
        np.testing.assert_allclose(hits.t[rows], found.t, rtol=1e-12)


def test_only_the_rays_no_large_primitive_answers_are_walked():
    scene = ground_and_clutter()
    accel = build(scene, "kdtree")
    origins, directions, t_min, t_max = rays_meeting_the_ground(2000, seed=4)
    rays = accel._prepare_rays(origins, directions, t_min, t_max)
    hit = np.zeros(len(origins), dtype=np.bool_)
    rest = unsettled_rays(accel._large_primitives, scene.kind, rays, hit_flags(hit))
    ground = ra.build(ra.TriangleMesh(scene.vertices, scene.faces[:2]), "none")
    np.testing.assert_array_equal(hit, ground.occluded(origins, directions, t_min, t_max))
    np.testing.assert_array_equal(rest.hit_slot, np.flatnonzero(~hit))
    np.testing.assert_array_equal(rest.origins, origins[~hit])
    np.testing.assert_array_equal(rest.t_max, t_max[~hit])
    assert 0.25 < hit.mean() < 0.75
    upward = directions.copy()
    upward[:, 1] = np.abs(upward[:, 1]) + 1.0
    unmoved = accel._prepare_rays(origins + [0, 0.01, 0], upward, 0.0, np.inf)
    assert unsettled_rays(accel._large_primitives, scene.kind, unmoved, hit_flags(hit)) is unmoved
    few = accel._prepare_rays(origins[:SAMPLED_RAYS - 1], directions[:SAMPLED_RAYS - 1], 0.0, np.inf)
    assert unsettled_rays(accel._large_primitives, scene.kind, few, hit_flags(hit)) is few


def test_every_ray_settled_and_unusable_rays_left_to_the_walk():
    accel = build(ground_and_clutter(), "kdtree")
    n = 1000
    origins = np.column_stack([np.linspace(0.1, 9.9, n), np.full(n, 5.0), np.linspace(0.1, 9.9, n)])
    directions = np.tile([0.0, -1.0, 0.0], (n, 1))
    assert accel.occluded(origins, directions).all()
    hits = accel.intersect(origins, directions, any_hit=True)
    assert (hits.prim >= 0).all()
    for bad, message in ((np.nan, "NaN"), (0.0, "zero")):
        broken = directions.copy()
        broken[n // 2] = bad
        with pytest.raises(ValueError, match=message):
            accel.occluded(origins, broken)


def test_a_large_sphere_settles_too():
    rng = np.random.default_rng(2)
    centres = np.vstack([[[5.0, 5.0, 5.0]], rng.uniform(0, 10, size=(300, 3))])
    spheres = ra.Spheres(centres, np.r_[4.0, np.full(300, 0.1)])
    origins = rng.uniform(0, 10, size=(2000, 3))
    directions = rng.normal(size=(2000, 3))
    reference = ra.build(spheres, "none")
    for method in SETTLING:
        accel = build(spheres, method)
        assert list(accel._large_primitives.prims) == [0]
        np.testing.assert_array_equal(accel.occluded(origins, directions, 0.0, 3.0),
                                      reference.occluded(origins, directions, 0.0, 3.0))


@pytest.mark.parametrize("method", ["kdtree", "grid"])
def test_the_rays_left_may_be_sorted_before_the_walk(method, monkeypatch):
    monkeypatch.setattr("rayaccel.structures.base.sorting_pays", lambda n_rays, structure_bytes: True)
    scene = ground_and_clutter()
    reference, accel = ra.build(scene, "none"), build(scene, method)
    origins, directions, t_min, t_max = rays_meeting_the_ground(3000, seed=6)
    np.testing.assert_array_equal(accel.occluded(origins, directions, t_min, t_max),
                                  reference.occluded(origins, directions, t_min, t_max))
    hits = accel.intersect(origins, directions, t_min, t_max, any_hit=True)
    np.testing.assert_array_equal(hits.prim >= 0, reference.occluded(origins, directions, t_min, t_max))


WALKS = ["single", "packets", "interleaved"]


def _walk_taken(monkeypatch, walk):
    """Make the kd-tree trace every closest-hit and any-hit batch with ``walk``."""
    monkeypatch.setattr(kd_accelerator, "packets_pay", lambda *args: walk == "packets")
    monkeypatch.setattr(kd_accelerator, "lane_packets_pay", lambda *args: False)
    monkeypatch.setattr(kd_accelerator, "interleaving_pays", lambda *args, **kwargs: walk == "interleaved")


def _ray_sets(scene, reference):
    """Rays over and onto the ground (per-ray intervals), camera rays, and shadow rays from the camera
    rays' hits to a light above the scene (partly occluded, ``t_max`` 1): ``(name, o, d, t_min, t_max)``."""
    origins, directions, t_min, t_max = rays_meeting_the_ground(3000, seed=8)
    eye, view = camera_rays(scene, 40)
    hits = reference.intersect(eye, view)
    hit = np.isfinite(hits.t)
    points = eye[hit] + hits.t[hit, None] * view[hit]
    light = np.array([0.3 * GROUND, 4.0 * GROUND, 0.6 * GROUND])
    return [("ground", origins, directions, t_min, t_max), ("camera", eye, view, 0.0, np.inf),
            ("shadow", points, light - points, 1e-6, 1.0)]


def test_the_kd_tree_is_built_without_the_large_primitives():
    scene = ground_and_clutter()
    apart, kept = ra.build(scene, "kdtree"), ra.build(scene, "kdtree", large_apart=False)
    np.testing.assert_array_equal(apart.apart_prims, [0, 1])
    assert set(apart.kd.leaf_prims.tolist()) == set(range(2, len(scene)))
    np.testing.assert_array_equal(apart.refs[apart.apart_first:], [0, 1])
    assert len(kept.apart_prims) == 0 and np.isin(kept.kd.leaf_prims, [0, 1]).sum() > 2
    assert not apart._large_primitives_first and kept._large_primitives_first
    stats, kept_stats = apart.stats(), kept.stats()
    assert stats["primitives_apart"] == 2 and kept_stats["primitives_apart"] == 0
    assert stats["references"] < kept_stats["references"] - 2
    two = ra.TriangleMesh(scene.vertices[:4], scene.faces[:2])
    assert len(ra.build(two, "kdtree").apart_prims) == 0


def _scene_in(layout):
    """The ground and clutter, its triangles in the kd-tree's indexed layout or, rounded to float32, in
    float32 lanes (:mod:`rayaccel.geometry.gather`)."""
    scene = ground_and_clutter()
    return scene if layout == "indexed" else ra.TriangleMesh(scene.vertices.astype(np.float32), scene.faces)


@pytest.mark.parametrize("layout", ["indexed", "lanes"])
@pytest.mark.parametrize("walk", WALKS)
def test_rays_through_the_kd_tree_and_beside_it_agree_with_brute_force(walk, layout, monkeypatch):
    _walk_taken(monkeypatch, walk)
    scene = _scene_in(layout)
    reference, accel = ra.build(scene, "none"), ra.build(scene, "kdtree")
    assert is_lanes(accel.geometry) == (layout == "lanes")
    for name, origins, directions, t_min, t_max in _ray_sets(scene, reference):
        expected = reference.intersect(origins, directions, t_min, t_max)
        for rays in ((origins, directions), (origins.astype(np.float32), directions.astype(np.float32))):
            want = expected if rays[0] is origins else reference.intersect(*rays, t_min, t_max)
            got = accel.intersect(*rays, t_min, t_max)
            np.testing.assert_array_equal(got.prim, want.prim, err_msg=name)
            np.testing.assert_allclose(got.t, want.t, rtol=1e-12, err_msg=name)
            np.testing.assert_array_equal(got.geom, want.geom, err_msg=name)
            np.testing.assert_array_equal(accel.occluded(*rays, t_min, t_max), want.prim >= 0, err_msg=name)
            np.testing.assert_array_equal(accel.intersect(*rays, t_min, t_max, any_hit=True).prim >= 0,
                                          want.prim >= 0, err_msg=name)
        assert np.isin(expected.prim, np.arange(2, len(scene))).any()
        assert np.isin(expected.prim, [0, 1]).any() == (name != "shadow")


@pytest.mark.parametrize("layout", ["indexed", "lanes"])
def test_counting_listing_and_points_beside_the_kd_tree_agree_with_brute_force(layout):
    scene = _scene_in(layout)
    reference, accel = ra.build(scene, "none"), ra.build(scene, "kdtree")
    kept = ra.build(scene, "kdtree", large_apart=False)
    for name, origins, directions, t_min, t_max in _ray_sets(scene, reference):
        np.testing.assert_array_equal(accel.count(origins, directions, t_min, t_max),
                                      reference.count(origins, directions, t_min, t_max), err_msg=name)
        for max_hits in (None, 1, 3):
            got = accel.intersect_all(origins, directions, t_min, t_max, max_hits=max_hits)
            want = reference.intersect_all(origins, directions, t_min, t_max, max_hits=max_hits)
            np.testing.assert_array_equal(got.offsets, want.offsets, err_msg=name)
            np.testing.assert_array_equal(got.prim, want.prim, err_msg=name)
            np.testing.assert_allclose(got.t, want.t, rtol=1e-12, err_msg=name)
    rng = np.random.default_rng(5)
    points = np.vstack([rng.uniform([-1, -1, -1], [GROUND + 1, 4, GROUND + 1], size=(1500, 3)),
                        [[5.0, 0.0, 5.0], [GROUND, -0.5, GROUND], [3.0, 0.0, 3.0]]])
    for max_distance in (np.inf, 0.3):
        got, want = accel.closest_point(points, max_distance), reference.closest_point(points, max_distance)
        np.testing.assert_array_equal(got.prim, want.prim)
        np.testing.assert_allclose(got.distance, want.distance, rtol=1e-12)
    assert set(accel.closest_point(points[[-3, -1]]).prim.tolist()) <= {0, 1}
    np.testing.assert_allclose(accel.winding_number(points), kept.winding_number(points), atol=1e-9)
    origins, directions, t_min, t_max = rays_meeting_the_ground(3000, seed=8)
    counters = accel.intersect(origins, directions, t_min, t_max, counters=True).counters
    down = np.arange(300, 600)
    reaching = down[(t_min[down] <= 2.0) & (t_max[down] >= 2.0)]
    assert len(reaching) > 200 and (counters.tests[reaching] >= 2).all()


def test_a_large_sphere_is_kept_apart_too():
    rng = np.random.default_rng(2)
    spheres = ra.Spheres(np.vstack([[[5.0, 5.0, 5.0]], rng.uniform(0, 10, size=(300, 3))]),
                         np.r_[4.0, np.full(300, 0.1)])
    reference, accel = ra.build(spheres, "none"), ra.build(spheres, "kdtree")
    np.testing.assert_array_equal(accel.apart_prims, [0])
    origins, directions = rng.uniform(0, 10, size=(2000, 3)), rng.normal(size=(2000, 3))
    got, want = accel.intersect(origins, directions, 0.0, 3.0), reference.intersect(origins, directions, 0.0, 3.0)
    np.testing.assert_array_equal(got.prim, want.prim)
    np.testing.assert_allclose(got.t, want.t, rtol=1e-12)
    np.testing.assert_array_equal(accel.count(origins, directions), reference.count(origins, directions))
    np.testing.assert_array_equal(accel.closest_point(origins).prim, reference.closest_point(origins).prim)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("method", ["kdtree", "grid-bvh"])
def test_rays_from_one_origin_settle_and_walk_with_that_origin(method, dtype):
    """A camera's rays given their eye once, through the structures whose walks take one origin:
    the large primitives settle most of them and the rest walk with the eye still given once,
    every answer that of brute force on the eye copied to every ray."""
    scene = ground_and_clutter()
    reference, accel = ra.build(scene, "none"), build(scene, method)
    camera = ra.Camera((4.0, 6.0, -3.0), (5.0, 0.0, 5.0), fov=50.0)
    origins, directions = (array.astype(dtype) for array in camera.rays(72, 64))
    eye = origins[0].copy()
    prepared = accel._prepare_rays(eye, directions, 0.0, np.inf)
    rest = unsettled_rays(accel._large_primitives, scene.kind, prepared, hit_flags(np.empty(len(directions), bool)))
    assert prepared.shares_origin and rest.shares_origin and 0 < rest.size < prepared.size
    t_max = np.random.default_rng(5).uniform(2.0, 12.0, len(directions))
    for limits in ((0.0, np.inf), (0.0, t_max)):
        expected = reference.occluded(origins, directions, *limits)
        assert 0.25 < expected.mean() < 1.0
        np.testing.assert_array_equal(accel.occluded(eye, directions, *limits), expected)
        hits = accel.intersect(eye, directions, *limits, any_hit=True)
        np.testing.assert_array_equal(hits.prim >= 0, expected)
    assert_same_hits(reference.intersect(origins, directions), accel.intersect(eye, directions))
