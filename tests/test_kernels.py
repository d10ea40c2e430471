"""The intersection kernels on their own: watertightness, signed zeros, precision."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import examples
from hypothesis import given, settings
from hypothesis import strategies as st

import rayaccel as ra
from rayaccel.geometry.box import clip_to_box


def edge_midpoints(mesh):
    edges = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    return 0.5 * (mesh.vertices[edges[:, 0]] + mesh.vertices[edges[:, 1]])


def cube_mesh():
    vertices = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    faces = np.array([
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ])
    return ra.TriangleMesh(vertices, faces)


@pytest.mark.parametrize("method", ["none", "grid"])
@pytest.mark.parametrize("mesh_name", ["sphere", "cube"])
def test_watertight_towards_every_vertex_and_edge(mesh_name, method):
    mesh = cube_mesh() if mesh_name == "cube" else ra.load_scene("sphere")
    accel = ra.build(mesh, method)
    targets = np.concatenate([mesh.vertices, edge_midpoints(mesh)])
    rng = np.random.default_rng(0)
    center = mesh.vertices.mean(axis=0)
    for origin in np.concatenate([center[None], center + rng.uniform(-0.3, 0.3, (4, 3))]):
        hits = accel.intersect(origin, targets - origin)
        assert hits.hit.all(), f"{(~hits.hit).sum()} rays escaped the closed mesh"


@settings(max_examples=examples(30), deadline=None)
@given(origin=st.tuples(*[st.floats(0.05, 0.95)] * 3))
def test_cube_is_watertight_from_any_inside_point(origin):
    mesh = cube_mesh()
    targets = np.concatenate([mesh.vertices, edge_midpoints(mesh)])
    hits = ra.build(mesh, "none").intersect(np.array(origin), targets - np.array(origin))
    assert hits.hit.all()


def test_signed_zero_directions_in_the_slab_test():
    lo, hi = np.zeros(3), np.ones(3)
    for zero in (0.0, -0.0):
        # on the face planes, parallel to them: inside (closed box)
        for face in (0.0, 1.0):
            enter, exit_ = clip_to_box(lo, hi, face, 0.5, -1.0, zero, zero, 1.0, 0.0, np.inf)
            assert enter <= exit_ and np.isfinite(enter) and not np.isnan(exit_)
        enter, exit_ = clip_to_box(lo, hi, 1.5, 0.5, -1.0, zero, zero, 1.0, 0.0, np.inf)
        assert enter > exit_


def test_barycentrics_reconstruct_the_hit_point():
    mesh = ra.load_scene("teapot")
    rng = np.random.default_rng(2)
    origins = rng.uniform(-4, 4, (2000, 3))
    directions = rng.normal(size=(2000, 3))
    hits = ra.build(mesh, "none").intersect(origins, directions)
    h = hits.hit
    corners = mesh.geometry[hits.prim[h]].reshape(-1, 3, 3)
    u, v = hits.u[h, None], hits.v[h, None]
    point = (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
    np.testing.assert_allclose(point, origins[h] + hits.t[h, None] * directions[h], atol=1e-9)
    assert np.isnan(hits.u[~h]).all()


def test_sphere_from_inside_tangent_and_far_away():
    spheres = ra.Spheres([[0.0, 0.0, 0.0], [1e6, 0.0, 0.0]], [1.0, 1e-3])
    accel = ra.build(spheres, "none")
    hits = accel.intersect([[0.0, 0.0, 0.0], [0.0, 1.0, -5.0], [0.0, 0.0, 0.0]],
                           [[0.0, 0.0, 2.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    assert hits.t[0] == pytest.approx(0.5)        # from inside: the far side, in units of |d| = 2
    assert hits.prim[1] == 0 and hits.t[1] == pytest.approx(5.0)   # tangent
    assert hits.t[2] == pytest.approx(1.0)        # inside the big sphere first
    far = accel.intersect([[2.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])
    assert far.prim[0] == 1 and far.t[0] == pytest.approx(1e6 - 2.0 - 1e-3, rel=1e-12)
    assert 0 <= hits.u[0] < 1 and 0 <= hits.v[0] <= 1


def test_degenerate_triangles_never_hit():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]])
    mesh = ra.TriangleMesh(vertices, [[0, 1, 2], [0, 0, 0], [0, 1, 3]])
    hits = ra.build(mesh, "grid").intersect([[0.5, 0.0, -1.0], [0.2, 0.2, -1.0]], [[0, 0, 1.0], [0, 0, 1.0]])
    assert hits.prim.tolist() == [2, 2]


def test_any_float_dtype_and_memory_order():
    mesh = ra.load_scene("spot")
    accel = ra.build(mesh, "grid")
    rng = np.random.default_rng(4)
    origins = rng.uniform(-2, 2, (500, 3))
    directions = rng.normal(size=(500, 3))
    reference = accel.intersect(origins, directions)
    as_f32 = accel.intersect(origins.astype(np.float32), np.asfortranarray(directions.astype(np.float32)))
    agree = np.mean(as_f32.prim == reference.prim)
    assert agree > 0.98
    np.testing.assert_array_equal(accel.intersect(np.asfortranarray(origins), directions[:, :]).prim, reference.prim)


def test_split_clipped_bounds_hold_every_point_of_each_half():
    from rayaccel.geometry.clip import CLIP_VERTICES, split_clipped_bounds

    rng = np.random.default_rng(3)
    triangles = rng.uniform(-0.2, 1.2, (300, 9))
    weights = np.array([(a, b) for a in np.linspace(0, 1, 25) for b in np.linspace(0, 1, 25) if a + b <= 1])
    poly, out = np.empty((2, CLIP_VERTICES, 3)), np.empty((2, 6))
    for prim, triangle in enumerate(triangles):
        corners = triangle.reshape(3, 3)
        points = corners[0] + weights[:, :1] * (corners[1] - corners[0]) + weights[:, 1:] * (corners[2] - corners[0])
        box = np.concatenate((rng.uniform(0.0, 0.4, 3), rng.uniform(0.6, 1.0, 3)))
        axis = prim % 3
        plane = rng.uniform(box[axis], box[axis + 3])
        sides = split_clipped_bounds(ra.scene.TRIANGLE, triangles, prim, box, axis, plane, 1e-12, poly, out)
        for side in range(2):
            half = box.copy()
            half[axis + 3 * (1 - side)] = plane
            inside = points[((points >= half[:3]) & (points <= half[3:])).all(axis=1)]
            if len(inside):
                assert sides & (1 << side)
            if sides & (1 << side):
                assert (out[side, :3] >= half[:3]).all() and (out[side, 3:] <= half[3:]).all()
                assert (inside >= out[side, :3] - 1e-12).all() and (inside <= out[side, 3:] + 1e-12).all()
                assert (out[side, :3] >= corners.min(axis=0) - 1e-12).all()
                assert (out[side, 3:] <= corners.max(axis=0) + 1e-12).all()
