"""rayaccel behind trimesh's interfaces (``rayaccel.integrations.trimesh``): the same answers as
trimesh's own engines wherever theirs are exact, exact answers where theirs are not, brute-force
proximity, meshes edited in place, pickling and copying, bad input."""

from __future__ import annotations

import copy
import pickle
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from trimesh.ray import ray_triangle

import rayaccel as ra
from rayaccel.catalog import data_directory
from rayaccel.integrations.trimesh import ProximityQuery, RayMeshIntersector

EMBREE = trimesh.ray.has_embree
needs_embree = pytest.mark.skipif(not EMBREE, reason="embreex is not installed")


def primitives():
    annulus = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.6)
    return {"box": trimesh.creation.box(extents=(1.0, 2.0, 0.5)), "icosphere": trimesh.creation.icosphere(2),
            "cylinder": trimesh.creation.cylinder(radius=0.7, height=1.5, sections=24), "annulus": annulus}


@pytest.fixture(scope="module")
def meshes():
    bunny = trimesh.load(data_directory() / "stanford-bunny.obj", force="mesh", process=False)
    return {**primitives(), "bunny": bunny}


def generic_rays(mesh, n, seed=0):
    """Origins in a box around the mesh, unit directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    pad = 0.3 * (hi - lo)
    origins = rng.uniform(lo - pad, hi + pad, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def hit_set(index_tri, index_ray):
    return set(zip(np.asarray(index_ray).tolist(), np.asarray(index_tri).tolist()))


def clear_rays(ours, origins, directions, margin=1e-4):
    """Rays whose every hit lies ``margin`` (relative) inside its triangle and apart from the ray's
    other hits: where float32 rays and re-casting from an offset origin cannot change the answer."""
    hits = ours.accelerator.intersect_all(origins, directions)
    scale = ours.mesh.scale
    inner = np.minimum(np.minimum(hits.u, hits.v), 1.0 - hits.u - hits.v) > margin
    gaps = np.diff(hits.t) > margin * scale
    same_ray = np.diff(hits.ray) == 0
    crowded = hits.ray[1:][same_ray & ~gaps]
    clear = np.ones(len(origins), dtype=bool)
    clear[hits.ray[~inner]] = False
    clear[crowded] = False
    return clear


@pytest.mark.parametrize("name", ["box", "icosphere", "cylinder", "annulus", "bunny"])
def test_hits_match_trimeshs_numpy_engine(meshes, name):
    mesh = meshes[name]
    ours, theirs = RayMeshIntersector(mesh), ray_triangle.RayMeshIntersector(mesh)
    origins, directions = generic_rays(mesh, 60 if name == "bunny" else 150, seed=1)
    assert hit_set(*ours.intersects_id(origins, directions)) == hit_set(*theirs.intersects_id(origins, directions))
    locations, index_ray, index_tri = ours.intersects_location(origins, directions)
    expected, ray_expected, tri_expected = theirs.intersects_location(origins, directions)
    ours_order, their_order = np.lexsort((index_tri, index_ray)), np.lexsort((tri_expected, ray_expected))
    np.testing.assert_allclose(locations[ours_order], expected[their_order], atol=1e-9 * mesh.scale)
    first = ours.intersects_first(origins, directions)
    np.testing.assert_array_equal(first >= 0, theirs.intersects_any(origins, directions))


@needs_embree
@pytest.mark.parametrize("name", ["box", "icosphere", "cylinder", "annulus", "bunny"])
def test_hits_match_trimeshs_embree_engine_where_it_is_exact(meshes, name):
    from trimesh.ray import ray_pyembree

    mesh = meshes[name]
    ours, theirs = RayMeshIntersector(mesh), ray_pyembree.RayMeshIntersector(mesh)
    origins, directions = generic_rays(mesh, 4000, seed=2)
    clear = clear_rays(ours, origins, directions)
    assert clear.mean() > 0.9
    o, d = origins[clear], directions[clear]
    found = ours.intersects_location(o, d)
    expected = theirs.intersects_location(o, d)
    assert hit_set(found[2], found[1]) == hit_set(expected[2], expected[1])
    ours_order, their_order = np.lexsort((found[2], found[1])), np.lexsort((expected[2], expected[1]))
    np.testing.assert_allclose(found[0][ours_order], expected[0][their_order], atol=1e-6 * mesh.scale)
    first_only = ours.intersects_location(o, d, multiple_hits=False)
    expected = theirs.intersects_location(o, d, multiple_hits=False)
    assert hit_set(first_only[2], first_only[1]) == hit_set(expected[2], expected[1])
    np.testing.assert_array_equal(ours.intersects_first(o, d), theirs.intersects_first(o, d))
    np.testing.assert_array_equal(ours.intersects_any(origins, directions), theirs.intersects_any(origins, directions))


def test_hits_are_grouped_by_ray_and_sorted_along_it(meshes):
    mesh = meshes["bunny"]
    ours = RayMeshIntersector(mesh)
    origins, directions = generic_rays(mesh, 500, seed=3)
    locations, index_ray, index_tri = ours.intersects_location(origins, directions)
    assert np.all(np.diff(index_ray) >= 0)
    t = np.einsum("ij,ij->i", locations - origins[index_ray], directions[index_ray])
    assert np.all(np.diff(t)[np.diff(index_ray) == 0] >= 0)
    counts = np.bincount(index_ray, minlength=len(origins))
    limited_tri, limited_ray = ours.intersects_id(origins, directions, max_hits=2)
    np.testing.assert_array_equal(np.bincount(limited_ray, minlength=len(origins)), np.minimum(counts, 2))
    firsts = np.flatnonzero(np.r_[True, np.diff(index_ray) > 0])
    single_tri, single_ray, single_at = ours.intersects_id(origins, directions, multiple_hits=False,
                                                           return_locations=True)
    np.testing.assert_array_equal(single_ray, index_ray[firsts])
    np.testing.assert_allclose(single_at, locations[firsts], rtol=0, atol=1e-12 * mesh.scale)


def two_sheets(gap):
    """Two unit right triangles, the second ``gap`` above the first."""
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, gap], [1, 0, gap], [0, 1, gap]]
    return trimesh.Trimesh(vertices, [[0, 1, 2], [3, 4, 5]], process=False)


def test_hits_closer_than_embrees_recast_offset_are_all_found():
    mesh = two_sheets(1e-7)
    origins = np.array([[0.2, 0.2, -1.0], [0.3, 0.1, 2.0], [0.1, 0.6, -0.5]])
    directions = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.01, -0.02, 1.0]])
    locations, index_ray, index_tri = RayMeshIntersector(mesh).intersects_location(origins, directions)
    np.testing.assert_array_equal(index_ray, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(index_tri, [0, 1, 1, 0, 0, 1])
    np.testing.assert_allclose(locations[:, 2], [0, 1e-7, 1e-7, 0, 0, 1e-7], rtol=1e-9, atol=1e-18)


def box_edge_rays(box, n, seed):
    """Unit rays through points on the diagonals of the box's faces (edges shared by the two triangles
    of each face), from 3 box diagonals away, so that every origin is outside the box."""
    rng = np.random.default_rng(seed)
    diagonals = box.face_adjacency_edges[box.face_adjacency_angles < 1e-9]
    edge = diagonals[rng.integers(len(diagonals), size=n)]
    s = rng.random(n)[:, None]
    through = box.vertices[edge[:, 0]] * (1 - s) + box.vertices[edge[:, 1]] * s
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return through - 3.0 * box.scale * directions, directions


def slab_entry_exit(box, origins, directions):
    lo, hi = box.bounds
    with np.errstate(divide="ignore"):
        near, far = (lo - origins) / directions, (hi - origins) / directions
    return np.minimum(near, far).max(axis=1), np.maximum(near, far).min(axis=1)


def test_a_crossing_through_a_shared_edge_is_reported_once():
    box = trimesh.creation.box()
    origins, directions = box_edge_rays(box, 1500, seed=4)
    index_tri, index_ray, locations = RayMeshIntersector(box).intersects_id(origins, directions, return_locations=True)
    np.testing.assert_array_equal(np.bincount(index_ray, minlength=len(origins)), 2)
    t_in, t_out = slab_entry_exit(box, origins, directions)
    expected = origins[:, None] + np.stack([t_in, t_out], axis=1)[:, :, None] * directions[:, None]
    np.testing.assert_allclose(locations, expected.reshape(-1, 3), atol=1e-12)
    assert not RayMeshIntersector(box).contains_points(origins).any()


def test_a_box_scaled_by_ten_thousand():
    box = trimesh.creation.box()
    box.apply_scale(1e4)
    box.apply_translation([3e4, -2e4, 5e3])
    origins, directions = box_edge_rays(box, 1000, seed=5)
    generic, generic_dirs = generic_rays(box, 1000, seed=6)
    origins, directions = np.concatenate([origins, generic]), np.concatenate([directions, generic_dirs])
    t_in, t_out = slab_entry_exit(box, origins, directions)
    hit = t_in < t_out
    entering = hit & (t_in > 0)
    expected_counts = entering.astype(int) + (hit & (t_out > 0))
    locations, index_ray, _ = RayMeshIntersector(box).intersects_location(origins, directions)
    np.testing.assert_array_equal(np.bincount(index_ray, minlength=len(origins)), expected_counts)
    t = np.einsum("ij,ij->i", locations - origins[index_ray], directions[index_ray])
    expected_t = np.where(np.r_[True, np.diff(index_ray) > 0] & entering[index_ray], t_in[index_ray],
                          t_out[index_ray])
    np.testing.assert_allclose(t, expected_t, rtol=1e-12, atol=1e-12 * box.scale)


@pytest.mark.parametrize("name", ["box", "icosphere", "cylinder", "annulus", "bunny"])
def test_contains_points_agrees_with_trimesh_away_from_the_surface(meshes, name):
    mesh = meshes[name]
    rng = np.random.default_rng(7)
    lo, hi = mesh.bounds
    points = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(80 if name == "bunny" else 200, 3))
    far = np.array([[1e6, 0.0, 0.0], [0.0, -1e7, 3e5], lo - 10.0 * mesh.scale])
    ours = RayMeshIntersector(mesh)
    distance = ra.build(mesh, "none").distance(points)
    away = distance > 0.01 * mesh.scale
    if name == "bunny":
        winding = ra.build(mesh, "none").winding_number(points[away], accuracy=np.inf)
        np.testing.assert_array_equal(ours.contains_points(points[away]), np.abs(winding) > 0.5)
    else:
        reference = ray_triangle.RayMeshIntersector(mesh).contains_points(points[away])
        np.testing.assert_array_equal(ours.contains_points(points[away]), reference)
    assert not ours.contains_points(far).any()
    at_vertices = ours.contains_points(mesh.vertices)
    assert at_vertices.dtype == bool and at_vertices.shape == (len(mesh.vertices),)


def test_contains_points_is_right_where_the_mesh_has_a_hole():
    box = trimesh.creation.box()
    holey = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)
    rng = np.random.default_rng(8)
    inside = rng.uniform(-0.4, 0.4, size=(300, 3))
    outside = rng.uniform(0.6, 2.0, size=(300, 3)) * rng.choice([-1.0, 1.0], size=(300, 3))
    ours = RayMeshIntersector(holey)
    assert ours.contains_points(inside).all()
    assert not ours.contains_points(outside).any()
    holey.ray = ours
    assert holey.contains(inside).all()


@pytest.mark.parametrize("name", ["icosphere", "annulus", "bunny"])
def test_proximity_equals_brute_force(meshes, name):
    mesh = meshes[name]
    rng = np.random.default_rng(9)
    lo, hi = mesh.bounds
    points = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), size=(80 if name == "bunny" else 300, 3))
    points = np.concatenate([points, mesh.vertices[:20], mesh.triangles[20:40].mean(axis=1)])
    nearest = ProximityQuery(mesh)
    brute = ra.build(mesh, "none").closest_point(points)
    closest, distance, triangle_id = nearest.on_surface(points)
    np.testing.assert_array_equal(closest, brute.point)
    np.testing.assert_array_equal(distance, brute.distance)
    np.testing.assert_array_equal(triangle_id, brute.prim)
    assert triangle_id.dtype == np.int64 and closest.shape == (len(points), 3)
    their_distance = trimesh.proximity.ProximityQuery(mesh).on_surface(points[:60])[1]
    assert np.all(distance[:60] <= their_distance * (1 + 1e-12))
    assert np.all(their_distance ** 2 - distance[:60] ** 2 <= trimesh.tol.merge)

    vertex_distance, vertex_id = nearest.vertex(points)
    for chunk in np.array_split(np.arange(len(points)), 8):
        gaps = np.linalg.norm(points[chunk, None] - mesh.vertices[None], axis=2)
        np.testing.assert_array_equal(vertex_id[chunk], gaps.argmin(axis=1))
        np.testing.assert_allclose(vertex_distance[chunk], gaps.min(axis=1), rtol=1e-12, atol=0)
    single = nearest.vertex(points[0])
    assert np.ndim(single[0]) == 0 and single[1] == vertex_id[0]

    signed = nearest.signed_distance(points)
    np.testing.assert_allclose(np.abs(signed), distance, rtol=0, atol=0)
    inside = np.abs(ra.build(mesh, "none").winding_number(points, accuracy=np.inf)) > 0.5
    off = distance > 1e-8
    np.testing.assert_array_equal((signed > 0)[off], inside[off])
    assert (signed[~off] >= 0).all()
    if name != "bunny":
        away = distance > 0.01 * mesh.scale
        theirs = trimesh.proximity.signed_distance(mesh, points[away])
        np.testing.assert_allclose(signed[away], theirs, rtol=1e-9)


def test_results_follow_the_mesh_when_it_is_edited_in_place():
    mesh = trimesh.creation.icosphere(2)
    mesh.ray, mesh.nearest = RayMeshIntersector(mesh), ProximityQuery(mesh)
    origins = np.array([[0.0, 0.0, -5.0], [3.0, 0.0, 0.0]])
    directions = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    points = np.array([[0.0, 0.0, 0.5], [0.0, 2.5, 0.0]])

    def check():
        fresh = trimesh.Trimesh(np.array(mesh.vertices), np.array(mesh.faces), process=False)
        expected = RayMeshIntersector(fresh)
        for found, wanted in zip(mesh.ray.intersects_location(origins, directions),
                                 expected.intersects_location(origins, directions)):
            np.testing.assert_array_equal(found, wanted)
        np.testing.assert_array_equal(mesh.ray.contains_points(points), expected.contains_points(points))
        np.testing.assert_array_equal(mesh.nearest.on_surface(points)[1], ProximityQuery(fresh).on_surface(points)[1])
        np.testing.assert_array_equal(mesh.nearest.vertex(points)[1], ProximityQuery(fresh).vertex(points)[1])

    check()
    accel = mesh.ray.accelerator
    mesh.vertices *= 4.0
    check()
    mesh.vertices[:, 0] += 3.0
    check()
    mesh.vertices[mesh.vertices[:, 2] > 0] *= 0.5
    check()
    assert mesh.ray.accelerator is accel and accel.refits == 3
    mesh.faces = mesh.faces[::2]
    check()
    assert mesh.ray.accelerator is not accel
    mesh.apply_translation([0.0, 0.0, 1.0])
    check()
    grid = RayMeshIntersector(mesh, "grid")
    grid.intersects_any(origins, directions)
    mesh.vertices[0] = [0.0, 0.0, -9.0]
    np.testing.assert_array_equal(grid.intersects_first(origins, directions), mesh.ray.intersects_first(origins,
                                                                                                         directions))


def test_one_structure_serves_ray_and_nearest_and_options_pass_through():
    mesh = trimesh.creation.icosphere(1)
    mesh.ray = RayMeshIntersector(mesh, "bvh-sah", max_leaf_size=2)
    mesh.nearest = ProximityQuery(mesh, "bvh-sah", max_leaf_size=2)
    mesh.nearest.on_surface([[0.0, 0.0, 2.0]])
    assert mesh.ray._structure._accel is not None and mesh.nearest._structure._accel is None
    assert mesh.ray.accelerator.method == "bvh-sah" and mesh.ray.accelerator.options["max_leaf_size"] == 2


def test_pickle_and_copy_as_trimeshs_engines_do():
    mesh = trimesh.creation.cylinder(radius=1.0, height=2.0)
    mesh.ray, mesh.nearest = RayMeshIntersector(mesh, "grid"), ProximityQuery(mesh)
    origins, directions = generic_rays(mesh, 50, seed=10)
    expected = mesh.ray.intersects_location(origins, directions)
    mesh.nearest.vertex(origins)
    loaded = pickle.loads(pickle.dumps(mesh))
    assert isinstance(loaded.ray, RayMeshIntersector) and loaded.ray.mesh is loaded
    assert loaded.ray._structure._accel is None and loaded.nearest._vertex_structure._accel is None
    for found, wanted in zip(loaded.ray.intersects_location(origins, directions), expected):
        np.testing.assert_array_equal(found, wanted)
    np.testing.assert_array_equal(loaded.nearest.vertex(origins)[1], mesh.nearest.vertex(origins)[1])
    for copied in (copy.copy(mesh.ray), copy.deepcopy(mesh.ray)):
        assert copied.mesh is mesh and copied.method == "grid" and copied._structure._accel is None
        np.testing.assert_array_equal(copied.intersects_first(origins, directions),
                                      mesh.ray.intersects_first(origins, directions))


@needs_embree
def test_shapes_and_dtypes_match_embrees_also_for_empty_queries(meshes):
    from trimesh.ray import ray_pyembree

    mesh = meshes["icosphere"]
    ours, theirs = RayMeshIntersector(mesh), ray_pyembree.RayMeshIntersector(mesh)
    rays = ([[0.0, 0.0, -5.0], [0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    empty = (np.zeros((0, 3)), np.zeros((0, 3)))
    for o, d in (rays, empty):
        for call in ("intersects_id", "intersects_location", "intersects_first", "intersects_any"):
            found, expected = getattr(ours, call)(o, d), getattr(theirs, call)(o, d)
            for a, b in zip(found if isinstance(found, tuple) else [found],
                            expected if isinstance(expected, tuple) else [expected]):
                assert a.dtype == b.dtype and a.shape == b.shape, call
        found = ours.intersects_id(o, d, return_locations=True, multiple_hits=False)
        expected = theirs.intersects_id(o, d, return_locations=True, multiple_hits=False)
        assert [(a.dtype, a.shape) for a in found] == [(b.dtype, b.shape) for b in expected]
        found, expected = ours.contains_points(o), theirs.contains_points(o)
        assert found.dtype == expected.dtype and found.shape == expected.shape
    nearest = ProximityQuery(mesh)
    assert [a.shape for a in nearest.on_surface(np.zeros((0, 3)))] == [(0, 3), (0,), (0,)]
    assert [a.shape for a in nearest.vertex(np.zeros((0, 3)))] == [(0,), (0,)]
    assert nearest.signed_distance(np.zeros((0, 3))).shape == (0,)
    fresh = RayMeshIntersector(mesh)
    fresh.intersects_location(*empty)
    assert fresh._structure._accel is None and nearest._structure._accel is None


def test_trimeshs_own_functions_run_on_it():
    mesh = trimesh.creation.icosphere(2)
    mesh.ray, mesh.nearest = RayMeshIntersector(mesh), ProximityQuery(mesh)
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [0.5, 0.0, 0.0]])
    np.testing.assert_array_equal(mesh.contains(points), [True, False, True])
    np.testing.assert_allclose(trimesh.proximity.longest_ray(mesh, points, [[1.0, 0.0, 0.0]] * 3),
                               [1.0, np.inf, 0.5], atol=1e-2)
    assert trimesh.proximity.signed_distance(mesh, points)[1] < 0


def test_bad_input_raises_value_error_naming_the_problem():
    mesh = trimesh.creation.box()
    ours, nearest = RayMeshIntersector(mesh), ProximityQuery(mesh)
    good = np.zeros((2, 3))
    cases = [
        (lambda: ours.intersects_id([[np.nan, 0, 0], [0, 0, 0]], [[1, 0, 0]] * 2), "NaN"),
        (lambda: ours.intersects_location(good, [[0, 0, 0], [1, 0, 0]]), "zero length"),
        (lambda: ours.intersects_any(good, np.ones((3, 3))), "same shape"),
        (lambda: ours.intersects_first(good, np.ones((2, 2))), "shape"),
        (lambda: ours.intersects_id(good, [["a", "b", "c"]] * 2), "real numbers"),
        (lambda: ours.intersects_id(good, np.ones((2, 3)), max_hits=0), "max_hits"),
        (lambda: ours.intersects_id(good, np.ones((2, 3)), max_hits=2.5), "max_hits"),
        (lambda: ours.contains_points([[0, 0, np.inf]]), "infinite"),
        (lambda: nearest.on_surface(np.ones((4, 2))), "shape"),
        (lambda: nearest.signed_distance([[np.nan, 0, 0]]), "NaN"),
        (lambda: RayMeshIntersector(mesh, "bvh-magic"), "unknown method"),
        (lambda: RayMeshIntersector(trimesh.Trimesh()).intersects_any(good, np.ones((2, 3))), "empty"),
    ]
    for call, words in cases:
        with pytest.raises(ValueError, match=words):
            call()


def test_import_rayaccel_imports_no_integration():
    code = "import sys, rayaccel; print(sorted(m for m in sys.modules if m.startswith(('trimesh', 'rayaccel.int'))))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
