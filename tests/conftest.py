"""Shared fixtures: real meshes, sphere scenes, the brute-force oracle and adversarial rays."""

from __future__ import annotations

import os

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# The grid cost model's C_i / C_c is a measurement; tests pin it so that no result depends on a timing.
os.environ["RAYACCEL_GRID_COST_RATIO"] = "triangle=2.6,sphere=1.0"

import rayaccel as ra  # noqa: E402
from rayaccel.structures.bvh.packet_slab import PACKET, bound_span  # noqa: E402
from rayaccel.structures.bvh.traverse_packet import SPAN  # noqa: E402

# ``pytest --hypothesis-profile=long`` searches the property-based tests far deeper than CI does.
settings.register_profile("long", max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def examples(ci_count: int) -> int:
    """A property test's ``max_examples``: ``ci_count``, or the long profile's count when that profile
    is loaded. A count given in ``@settings`` overrides the loaded profile's, so without this the long
    profile ran each test's CI count."""
    long_count = settings.get_profile("long").max_examples
    return long_count if settings.default.max_examples == long_count else ci_count


@pytest.fixture(scope="session")
def bunny():
    return ra.load_scene("bunny")


@pytest.fixture(scope="session")
def small_dragon():
    return ra.load_scene("dragon-11k")


@pytest.fixture(scope="session")
def closed_sphere_mesh():
    return ra.load_scene("sphere")


@pytest.fixture(scope="session")
def spheres():
    return ra.random_spheres(3000, seed=7)


@numba.njit(cache=False)
def bound_whole_span(origins, directions, bounds):
    """:func:`rayaccel.structures.bvh.packet_slab.bound_span` of the first ``SPAN`` rows, as two
    runs of half a span. Not cached: Numba's cache checks only this file's time stamp, and would keep
    an old ``bound_span`` compiled in after ``packet_slab`` changed."""
    return bound_span(origins, directions, 0, SPAN // 2, SPAN // PACKET, bounds)


def camera_rays(scene, size):
    b = scene.bounds()
    return ra.Camera.framing(b.scene_lo, b.scene_hi).rays(size, size)


GROUND = 10.0


def ground_and_clutter(n_small=400, seed=3):
    """A square ground :data:`GROUND` wide of two triangles at ``y = 0`` (faces 0 and 1) under small random
    triangles."""
    rng = np.random.default_rng(seed)
    ground = np.array([[0, 0, 0], [GROUND, 0, 0], [GROUND, 0, GROUND], [0, 0, GROUND]], dtype=float)
    centres = rng.uniform([0, 0.2, 0], [GROUND, 3, GROUND], size=(n_small, 1, 3))
    small = (centres + rng.normal(scale=0.3, size=(n_small, 3, 3))).reshape(-1, 3)
    faces = np.vstack([[[0, 1, 2], [0, 2, 3]], 4 + np.arange(3 * n_small).reshape(-1, 3)])
    return ra.TriangleMesh(np.vstack([ground, small]), faces)


def random_rays(scene, n, seed=0):
    """Incoherent rays: origins in a box around the scene, random directions."""
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    lo, hi = b.scene_lo, b.scene_hi
    pad = 0.3 * (hi - lo)
    origins = rng.uniform(lo - pad, hi + pad, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    return origins, directions


def vertex_and_edge_rays(mesh, n, seed=0):
    """Rays from outside aimed exactly at mesh vertices and edge midpoints."""
    rng = np.random.default_rng(seed)
    b = mesh.bounds()
    center = 0.5 * (b.scene_lo + b.scene_hi)
    radius = np.linalg.norm(b.scene_hi - b.scene_lo)
    faces = mesh.faces[rng.integers(0, len(mesh.faces), n)]
    targets = mesh.vertices[faces[:, 0]].copy()
    half = n // 2
    targets[:half] = 0.5 * (mesh.vertices[faces[:half, 0]] + mesh.vertices[faces[:half, 1]])
    directions_out = rng.normal(size=(n, 3))
    directions_out /= np.linalg.norm(directions_out, axis=1, keepdims=True)
    origins = center + 2.0 * radius * directions_out
    return origins, targets - origins


def axis_parallel_rays(scene, n, seed=0):
    """Rays along +-x, +-y, +-z with components of +0 and -0, from around the scene."""
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    lo, hi = b.scene_lo, b.scene_hi
    origins = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(n, 3))
    directions = np.zeros((n, 3))
    axis = rng.integers(0, 3, n)
    directions[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
    negative_zero = rng.random((n, 3)) < 0.5
    directions[(directions == 0) & negative_zero] = -0.0
    return origins, directions


def one_eye_vertex_and_edge_rays(mesh, n, eye_offset, seed=5):
    """Rays from one eye, at ``eye_offset`` times the mesh's size from its centre, aimed exactly at
    ``n`` vertices and edge midpoints and sorted by direction, so that neighbouring rays head
    alike as a camera's do."""
    rng = np.random.default_rng(seed)
    b = mesh.bounds()
    faces = mesh.faces[rng.integers(0, len(mesh.faces), n)]
    targets = mesh.vertices[faces[:, 0]].copy()
    targets[::2] = 0.5 * (mesh.vertices[faces[::2, 0]] + mesh.vertices[faces[::2, 1]])
    eye = 0.5 * (b.scene_lo + b.scene_hi) + np.asarray(eye_offset) * np.max(b.scene_hi - b.scene_lo)
    directions = targets - eye
    directions = directions[np.lexsort((directions[:, 0] // 1e-3, directions[:, 1] // 1e-3))]
    return np.broadcast_to(eye, directions.shape).copy(), directions


def assert_same_hits(reference, hits):
    """Hit for hit: the same primitive, the same distance and barycentrics; where both carry
    ``geom`` and the scene is a plain mesh or sphere set, 0 on a hit and -1 on a miss."""
    np.testing.assert_array_equal(hits.prim, reference.prim)
    hit = reference.prim >= 0
    if isinstance(hits.geom, np.ndarray) and isinstance(reference.geom, np.ndarray) and not (reference.geom > 0).any():
        np.testing.assert_array_equal(hits.geom, np.where(hit, 0, -1))
    np.testing.assert_allclose(hits.t[hit], reference.t[hit], rtol=1e-12, atol=0)
    np.testing.assert_allclose(hits.u[hit], reference.u[hit], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(hits.v[hit], reference.v[hit], rtol=1e-9, atol=1e-12)
    assert np.isinf(hits.t[~hit]).all()


def assert_one_and_twin_triangles_hit(method):
    """A scene of one triangle, and one of two identical triangles (the lower index must win),
    each hit straight down through the triangle."""
    corners = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    hits = ra.build(ra.TriangleMesh(corners, [[0, 1, 2]]), method).intersect([[0.2, 0.2, 1.0]], [[0, 0, -1.0]])
    assert hits.prim[0] == 0 and hits.t[0] == pytest.approx(1.0)
    twins = ra.TriangleMesh(corners, [[0, 1, 2], [0, 1, 2]])
    assert ra.build(twins, method).intersect([[0.2, 0.2, 1.0]], [[0, 0, -1.0]]).prim[0] == 0


def assert_counts_and_lists_match(reference, accel, origins, directions):
    """``accel`` counts and lists (all hits, and the nearest two) what ``reference`` does."""
    np.testing.assert_array_equal(accel.count(origins, directions), reference.count(origins, directions))
    for max_hits in (None, 2):
        expected = reference.intersect_all(origins, directions, max_hits=max_hits)
        found = accel.intersect_all(origins, directions, max_hits=max_hits)
        np.testing.assert_array_equal(found.offsets, expected.offsets)
        np.testing.assert_array_equal(found.prim, expected.prim)
        np.testing.assert_allclose(found.t, expected.t, rtol=1e-12)
