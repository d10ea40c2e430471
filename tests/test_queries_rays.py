"""All hits and hit counts: every method against brute force, brute force against a numpy oracle, one crossing
per shared edge or vertex (parity on closed meshes), duplicates, degenerate triangles, max_hits, intervals,
scenes of instances, bad input and Dask."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import axis_parallel_rays, camera_rays, examples, random_rays, vertex_and_edge_rays
from hypothesis import given, settings
from hypothesis import strategies as st

import rayaccel as ra

METHODS = ra.methods()


def numpy_crossings(mesh, origins, directions):
    """Every (ray, prim, t) where a ray crosses a triangle's interior, in float64 numpy
    (Moeller & Trumbore 1997): the oracle for generic rays, which touch no edge."""
    v0, v1, v2 = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(directions[:, None, :], e2[None])
    det = np.einsum("fk,rfk->rf", e1, p)
    s = origins[:, None, :] - v0[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.einsum("rfk,rfk->rf", s, p) / det
        q = np.cross(s, e1[None])
        v = np.einsum("rk,rfk->rf", directions, q) / det
        t = np.einsum("fk,rfk->rf", e2, q) / det
    hit = (np.abs(det) > 1e-300) & (u > 0) & (v > 0) & (u + v < 1) & (t >= 0)
    ray, prim = np.nonzero(hit)
    return ray, prim, t[ray, prim]


def as_lists(found):
    """Per ray, the list of (prim, geom) in the order reported."""
    return [list(zip(found.prim[a:b].tolist(), found.geom[a:b].tolist()))
            for a, b in zip(found.offsets[:-1], found.offsets[1:])]


def assert_same_lists(reference, found):
    np.testing.assert_array_equal(found.offsets, reference.offsets)
    np.testing.assert_array_equal(found.prim, reference.prim)
    np.testing.assert_array_equal(found.geom, reference.geom)
    np.testing.assert_allclose(found.t, reference.t, rtol=1e-12, atol=0)
    np.testing.assert_allclose(found.u, reference.u, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(found.v, reference.v, rtol=1e-9, atol=1e-12)


def assert_sorted(found):
    for a, b in zip(found.offsets[:-1], found.offsets[1:]):
        keys = list(zip(found.t[a:b], found.geom[a:b], found.prim[a:b]))
        assert keys == sorted(keys)


def cube_mesh(cells=1, flip=()):
    """The closed cube [-1, 1]^3, each face cut into ``cells`` x ``cells`` squares of two triangles,
    outward-facing except the triangles in ``flip``; every vertex has coordinates k / cells * 2 - 1."""
    ticks = np.linspace(-1.0, 1.0, cells + 1)
    vertices, faces = [], []
    for axis in range(3):
        for side in (-1.0, 1.0):
            a, b = (axis + 1) % 3, (axis + 2) % 3
            base = len(vertices)
            for i in range(cells + 1):
                for j in range(cells + 1):
                    point = np.zeros(3)
                    point[axis], point[a], point[b] = side, ticks[i], ticks[j]
                    vertices.append(point)
            for i in range(cells):
                for j in range(cells):
                    p00 = base + i * (cells + 1) + j
                    p10, p01, p11 = p00 + cells + 1, p00 + 1, p00 + cells + 2
                    quad = [[p00, p10, p11], [p00, p11, p01]] if (i + j) % 2 else [[p00, p10, p01], [p10, p11, p01]]
                    faces += [tri if side > 0 else tri[::-1] for tri in quad]
    faces = np.array(faces)
    faces[list(flip)] = faces[list(flip)][:, ::-1]
    return ra.TriangleMesh(np.array(vertices), faces)


def lattice_rays(mesh, origins):
    """From each origin, a ray aimed exactly at every vertex and every edge midpoint of the mesh."""
    edges = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    targets = np.unique(np.concatenate([mesh.vertices, 0.5 * (mesh.vertices[edges[:, 0]]
                                                               + mesh.vertices[edges[:, 1]])]), axis=0)
    o = np.repeat(origins, len(targets), axis=0)
    d = np.tile(targets, (len(origins), 1)) - o
    keep = np.any(d != 0, axis=1)
    return o[keep], d[keep]


@pytest.fixture(scope="module")
def scenes(small_dragon, closed_sphere_mesh, spheres):
    return {"dragon": small_dragon, "sphere-mesh": closed_sphere_mesh, "spheres": ra.random_spheres(400, seed=3)}


@pytest.fixture(scope="module")
def references(scenes):
    result = {}
    for name, scene in scenes.items():
        origins, directions = random_rays(scene, 150, seed=1)
        cam_o, cam_d = camera_rays(scene, 12)
        ax_o, ax_d = axis_parallel_rays(scene, 60, seed=2)
        parts = [(origins, directions), (cam_o, cam_d), (ax_o, ax_d)]  # the first 294 rays touch no edge
        if isinstance(scene, ra.TriangleMesh):
            parts.append(vertex_and_edge_rays(scene, 80, seed=3))
        o = np.concatenate([p[0] for p in parts])
        d = np.concatenate([p[1] for p in parts])
        brute = ra.build(scene, "none")
        result[name] = (o, d, brute.intersect_all(o, d), brute.count(o, d))
    return result


@pytest.mark.parametrize("method", METHODS)
def test_every_method_lists_and_counts_what_brute_force_does(method, scenes, references):
    for name, scene in scenes.items():
        o, d, reference, counts = references[name]
        accel = ra.build(scene, method)
        found = accel.intersect_all(o, d)
        assert_same_lists(reference, found)
        np.testing.assert_array_equal(accel.count(o, d), counts)
        np.testing.assert_array_equal(np.diff(found.offsets), counts)
        generic = slice(0, 294)
        closest = accel.intersect(o[generic], d[generic])
        hit = counts[generic] > 0
        np.testing.assert_array_equal(closest.prim >= 0, hit, err_msg=f"{method} on {name}")
        np.testing.assert_array_equal(found.t[found.offsets[:294][hit]], closest.t[hit])


def test_brute_force_matches_the_numpy_oracle(bunny, scenes, references):
    for mesh in (bunny, scenes["dragon"]):
        origins, directions = random_rays(mesh, 40, seed=5)
        found = ra.build(mesh, "none").intersect_all(origins, directions)
        assert_sorted(found)
        pieces = [numpy_crossings(mesh, origins[a:a + 4], directions[a:a + 4]) for a in range(0, 40, 4)]
        ray = np.concatenate([piece[0] + 4 * k for k, piece in enumerate(pieces)])
        prim, t = (np.concatenate([piece[j] for piece in pieces]) for j in (1, 2))
        order = np.lexsort((prim, t, ray))
        np.testing.assert_array_equal(np.bincount(ray, minlength=len(origins)), np.diff(found.offsets))
        np.testing.assert_array_equal(found.prim, prim[order])
        np.testing.assert_allclose(found.t, t[order], rtol=1e-9)
    for name in ("spheres", "sphere-mesh"):
        assert_sorted(references[name][2])


def test_mailboxes_off_still_count_each_primitive_once(small_dragon, references):
    o, d, reference, counts = references["dragon"]
    for method in ("grid", "hgrid", "grid-bvh"):
        accel = ra.build(small_dragon, method, mailbox=False)
        np.testing.assert_array_equal(accel.count(o, d), counts)
        assert_same_lists(reference, accel.intersect_all(o, d))


@pytest.mark.parametrize("method", ["none", "bvh-binned", "bvh-sah", "kdtree", "grid", "octree", "hgrid"])
def test_parity_through_vertices_and_edges_of_cubes(method):
    inside = np.array([[0.0, 0.0, 0.0], [0.5, 0.25, -0.125], [-0.75, 0.5, 0.25]])
    outside = np.array([[-3.0, -2.0, -1.5], [2.0, 0.5, 0.0], [0.0, 0.0, 4.0], [1.5, 1.5, 1.5]])
    for mesh in (cube_mesh(1), cube_mesh(4, flip=range(0, 192, 7))):
        accel = ra.build(mesh, method)
        for origins, parity in ((inside, 1), (outside, 0)):
            o, d = lattice_rays(mesh, origins)
            counts = accel.count(o, d)
            assert (counts % 2 == parity).all(), f"{method}: {np.count_nonzero(counts % 2 != parity)} wrong parities"


def test_parity_on_the_closed_icosphere(closed_sphere_mesh):
    mesh = closed_sphere_mesh
    center = mesh.vertices.mean(axis=0)
    radius = np.linalg.norm(mesh.vertices - center, axis=1).min()
    rng = np.random.default_rng(4)
    inner = center + 0.5 * radius * rng.uniform(-1, 1, (3, 3)) / np.sqrt(3)
    outer = center + 3.0 * radius * rng.normal(size=(3, 3)) / np.sqrt(3) + 2.0 * radius
    for method in ("none", "bvh-binned", "kdtree"):
        accel = ra.build(mesh, method)
        for origins, parity in ((inner, 1), (outer, 0)):
            o, d = lattice_rays(mesh, origins)
            counts = accel.count(o, d)
            assert (counts % 2 == parity).all()
            if parity:
                assert (counts == 1).all()


@settings(max_examples=examples(40), deadline=None)
@given(st.lists(st.integers(-24, 24), min_size=6, max_size=6))
def test_parity_property_on_dyadic_rays(coordinates):
    """Origins and targets on a lattice of 1/8: rays through vertices, edges and faces of the cut cube."""
    origin = np.array(coordinates[:3], float) / 8.0
    target = np.array(coordinates[3:], float) / 8.0
    if (origin == target).all() or ((np.abs(origin) == 1.0).any() and (np.abs(origin) <= 1.0).all()):
        return
    accel = _cut_cube_bvh()
    count = accel.count(origin[None], (target - origin)[None])[0]
    assert count % 2 == int((np.abs(origin) < 1.0).all())


_CUT_CUBE = {}


def _cut_cube_bvh():
    if not _CUT_CUBE:
        _CUT_CUBE["bvh"] = ra.build(cube_mesh(4), "bvh-binned")
    return _CUT_CUBE["bvh"]


@pytest.mark.parametrize("method", ["none", "bvh-binned", "grid", "kdtree"])
def test_duplicates_both_reported_degenerates_never(method):
    vertices = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 0], [0, 0, 2], [0, 0, 4]]
    faces = [[0, 1, 2], [0, 1, 2], [0, 3, 0], [0, 4, 5], [1, 2, 0]]
    accel = ra.build(ra.TriangleMesh(vertices, faces), method)
    found = accel.intersect_all([[0.2, 0.2, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 3.0]],
                                [[0, 0, -1.0], [-1.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    counts = np.diff(found.offsets)
    assert found.prim[:counts[0]].tolist() == [0, 1, 4]
    assert counts[1] == 0 and counts[2] in (0, 3)
    assert 2 not in found.prim.tolist() and 3 not in found.prim.tolist()


def test_spheres_cross_twice_from_outside_once_from_inside_twice_tangent():
    accel = ra.build(ra.Spheres([[0.0, 0.0, 0.0]], [1.0]), "bvh-binned")
    origins = [[-2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-2.0, 1.0, 0.0], [-2.0, 1.5, 0.0]]
    directions = [[1.0, 0.0, 0.0]] * 4
    np.testing.assert_array_equal(accel.count(origins, directions), [2, 1, 2, 0])
    found = accel.intersect_all(origins, directions)
    np.testing.assert_allclose(found.t, [1.0, 3.0, 1.0, 2.0, 2.0])
    assert np.isfinite(found.u).all() and np.isfinite(found.v).all()


@pytest.mark.parametrize("method", ["none", "bvh-binned", "grid-bvh", "kdtree", "octree"])
def test_max_hits_keeps_the_nearest(method, scenes, references):
    o, d, reference, counts = references["sphere-mesh"]
    found = ra.build(scenes["sphere-mesh"], method).intersect_all(o, d, max_hits=1)
    np.testing.assert_array_equal(np.diff(found.offsets), np.minimum(counts, 1))
    np.testing.assert_array_equal(found.prim, reference.prim[reference.offsets[:-1][counts > 0]])
    o, d, reference, counts = references["dragon"]
    limited = ra.build(scenes["dragon"], method).intersect_all(o, d, max_hits=3)
    expected = [hits[:3] for hits in as_lists(reference)]
    assert as_lists(limited) == expected


@pytest.mark.parametrize("slots", [(), (1,), (1, 2), (2, 3, 5)])
def test_listing_walks_of_any_slot_sizes_find_the_same_hits(slots, scenes, references, monkeypatch):
    import rayaccel.structures.base as base

    monkeypatch.setattr(base, "LIST_SLOTS", slots)
    monkeypatch.setattr(base, "LIST_BATCH", 97)
    for name in ("dragon", "spheres"):
        o, d, reference, counts = references[name]
        for method in ("none", "bvh-binned"):
            accel = ra.build(scenes[name], method)
            assert_same_lists(reference, accel.intersect_all(o, d))
            limited = accel.intersect_all(o, d, max_hits=2)
            assert as_lists(limited) == [hits[:2] for hits in as_lists(reference)]


def test_intervals_are_closed_per_ray_and_may_be_empty(small_dragon, references):
    o, d, reference, counts = references["dragon"]
    accel = ra.build(small_dragon, "bvh-binned")
    rows = np.flatnonzero(counts >= 2)
    second = reference.t[reference.offsets[rows] + 1]
    t_min = np.zeros(len(o))
    t_max = np.full(len(o), np.inf)
    t_min[rows] = second
    t_max[rows] = second
    within = accel.count(o, d, t_min, t_max)
    assert (within[rows] >= 1).all()
    assert (accel.count(o, d, 2.0, 1.0) == 0).all()
    assert accel.intersect_all(o, d, 2.0, 1.0).offsets[-1] == 0


def test_rays_starting_on_the_surface_count_the_start():
    accel = ra.build(cube_mesh(1), "bvh-binned")
    on_face = np.array([[1.0, 0.25, 0.5], [-0.5, -1.0, 0.125], [0.75, -0.25, 1.0]])
    outward = np.array([[1.0, 0.3, 0.2], [0.1, -1.0, 0.2], [-0.2, 0.1, 1.0]])
    found = accel.intersect_all(on_face, outward)
    assert np.diff(found.offsets).tolist() == [1, 1, 1] and (found.t == 0.0).all()
    assert (accel.count(on_face, outward, t_min=1e-9) == 0).all()
    assert accel.count(on_face, -outward).tolist() == [2, 2, 2]
    assert accel.count(on_face, -outward, t_min=1e-9).tolist() == [1, 1, 1]


def test_scene_of_instances_matches_its_flattened_mesh(small_dragon):
    scene = ra.Scene()
    scene.add(small_dragon)
    moved = np.eye(4)
    moved[:3, :3] = 0.5 * np.eye(3)
    moved[:3, 3] = [0.05, 0.0, 0.0]
    scene.add(small_dragon, transform=moved)
    o, d = random_rays(small_dragon, 150, seed=8)
    flat = ra.build(scene.flatten(), "none")
    for method in ("bvh-binned", "grid"):
        accel = ra.build(scene, method)
        counts = accel.count(o, d)
        np.testing.assert_array_equal(counts, flat.count(o, d))
        found = accel.intersect_all(o, d)
        reference = flat.intersect_all(o, d)
        np.testing.assert_array_equal(found.offsets, reference.offsets)
        np.testing.assert_allclose(found.t, reference.t, rtol=1e-9)
        n_prims = len(small_dragon.faces)
        np.testing.assert_array_equal(found.geom * n_prims + found.prim, reference.prim)
        limited = accel.intersect_all(o, d, max_hits=2)
        assert as_lists(limited) == [hits[:2] for hits in as_lists(found)]


def test_bad_and_empty_input(small_dragon):
    accel = ra.build(small_dragon, "bvh-binned")
    o = np.zeros((2, 3))
    d = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    for query in (accel.count, accel.intersect_all):
        with pytest.raises(ValueError):
            query(np.array([[np.nan, 0, 0], [0, 0, 0]]), d)
        with pytest.raises(ValueError):
            query(o, np.array([[0.0, 0, 0], [1, 0, 0]]))
        with pytest.raises(ValueError):
            query(o, np.ones((3, 3)))
        with pytest.raises(ValueError):
            query(o, d, t_min=np.array([0.0, np.nan]))
        with pytest.raises(TypeError):
            query(o.astype(object), d)
    for bad, error in ((0, ValueError), (-2, ValueError), (1.5, TypeError), ("3", TypeError)):
        with pytest.raises(error):
            accel.intersect_all(o, d, max_hits=bad)
    empty = np.zeros((0, 3))
    counts = accel.count(empty, empty)
    assert counts.shape == (0,) and counts.dtype == np.int64
    found = accel.intersect_all(empty, empty)
    assert found.offsets.tolist() == [0] and found.offsets.dtype == np.int64
    assert found.t.shape == (0,) and found.prim.dtype == np.int64 and found.geom.dtype == np.int64


def test_dask_arrays_in_dask_arrays_out(small_dragon, references):
    da = pytest.importorskip("dask.array")
    import dask

    o, d, reference, counts = references["dragon"]
    accel = ra.build(small_dragon, "bvh-binned")
    lazy_counts = accel.count(da.from_array(o, chunks=100), da.from_array(d, chunks=100))
    np.testing.assert_array_equal(lazy_counts.compute(), counts)
    lazy = accel.intersect_all(da.from_array(o, chunks=100), d, max_hits=None)
    offsets, t, prim, geom = dask.compute(lazy.offsets, lazy.t, lazy.prim, lazy.geom)
    np.testing.assert_array_equal(offsets, reference.offsets)
    np.testing.assert_array_equal(prim, reference.prim)
    np.testing.assert_array_equal(t, reference.t)
    assert (geom == 0).all()
