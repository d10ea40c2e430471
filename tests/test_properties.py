"""Property-based checks: generated scenes and queries that the hand-written tests do not cover.

Scenes are built from a small integer lattice, so that duplicated triangles, shared
edges and vertices, zero-area and collinear triangles and axis-aligned edges are
common, then scaled (1e-20 to 1e20) and moved (a scene at x = 1e7); slivers get one
corner nudged off its line. Sphere sets overlap, touch, nest and coincide. Rays start
on vertices, edge midpoints and surfaces or around the scene, run along the lattice's
directions (axis-parallel ones included) or at random, with per-ray ``t_min``/``t_max``
and empty intervals. Every method, with options at their extremes, must give brute
force's closest hits (same tie rule) and any-hit answers, and consistent counters.

The default profile keeps CI short; ``pytest --hypothesis-profile=long`` searches deeper.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_same_hits, examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rayaccel as ra

VARIANTS = [
    ("grid", {}), ("grid", {"resolution": (1, 1, 1)}), ("grid", {"density": 64.0, "insert": "exact"}),
    ("grid", {"mailbox": False}), ("hgrid", {}), ("grid-bvh", {}), ("octree", {}), ("octree", {"leaf_size": 1}),
    ("kdtree", {}), ("kdtree", {"leaf_size": 1}), ("kdtree", {"leaf_size": 64}), ("kdtree", {"exact_below": 0}),
    ("kdtree", {"width": 2}),
    *[(method, {}) for method in ra.methods() if method.startswith("bvh-")],
    ("bvh-binned", {"max_leaf_size": 1}), ("bvh-binned", {"max_leaf_size": 64}), ("bvh-binned", {"width": 2}),
    ("bvh-binned", {"bounds": "sphere"}), ("bvh-binned", {"bounds": "kdop"}),
    ("bvh-sah", {"bounds": "sphere", "sphere_fit": "children"}), ("hgrid", {"threshold": 1, "max_levels": 4}),
    ("grid-bvh", {"threshold": 1, "max_leaf_size": 1}),
]

SCALES = [1e-20, 1e-6, 1.0, 1e6, 1e20]


@st.composite
def triangle_scenes(draw):
    """``(mesh, lattice_to_world)``: a few triangles over lattice points, scaled and moved."""
    n_vertices = draw(st.integers(3, 12))
    lattice = np.array(draw(st.lists(st.tuples(*[st.integers(0, 3)] * 3), min_size=n_vertices,
                                     max_size=n_vertices)), dtype=float)
    n_faces = draw(st.integers(1, 16))
    faces = np.array(draw(st.lists(st.tuples(*[st.integers(0, n_vertices - 1)] * 3), min_size=n_faces,
                                   max_size=n_faces)), dtype=np.int64)
    if draw(st.booleans()):
        faces = np.concatenate((faces, faces[: draw(st.integers(1, n_faces))]))
    if draw(st.booleans()):
        lattice[draw(st.integers(0, n_vertices - 1))] += draw(st.sampled_from([1e-9, 1e-12, -1e-7]))
    scale = draw(st.sampled_from(SCALES))
    offset = np.array([draw(st.sampled_from([0.0, 1e7])), 0.0, 0.0]) if scale == 1.0 else np.zeros(3)

    def to_world(points):
        return offset + scale * np.asarray(points, float)

    return ra.TriangleMesh(to_world(lattice), faces), to_world, lattice, faces


@st.composite
def sphere_scenes(draw):
    """Spheres on lattice centres with radii that make them overlap, touch, nest or coincide."""
    n = draw(st.integers(1, 10))
    centers = np.array(draw(st.lists(st.tuples(*[st.integers(0, 3)] * 3), min_size=n, max_size=n)), dtype=float)
    radii = np.array(draw(st.lists(st.sampled_from([0.25, 0.5, 1.0, 1.5]), min_size=n, max_size=n)))
    if draw(st.booleans()):
        centers = np.concatenate((centers, centers[:1]))
        radii = np.concatenate((radii, radii[:1] * draw(st.sampled_from([1.0, 0.5]))))
    scale = draw(st.sampled_from(SCALES))
    return ra.Spheres(scale * centers, scale * radii), scale


def _lattice_rays(draw, points, n):
    """Rays from ``points`` (on surfaces, vertices, edges, or around) along lattice or random directions."""
    origins = points[np.array(draw(st.lists(st.integers(0, len(points) - 1), min_size=n, max_size=n)))]
    steps = np.array(draw(st.lists(st.tuples(*[st.integers(-2, 2)] * 3), min_size=n, max_size=n)), dtype=float)
    steps[np.abs(steps).sum(axis=1) == 0] = [0.0, 0.0, -1.0]
    return origins, steps


def _limits(draw, n):
    """Per-ray ``t_min``/``t_max``: mostly open, some bounded, some empty intervals."""
    t_min = np.array(draw(st.lists(st.sampled_from([0.0, 0.0, 0.5, 2.0]), min_size=n, max_size=n)))
    t_max = np.array(draw(st.lists(st.sampled_from([np.inf, np.inf, 1.0, 0.25]), min_size=n, max_size=n)))
    return t_min, t_max


def _check(scene, origins, directions, t_min, t_max, variant):
    method, options = variant
    reference = ra.build(scene, "none").intersect(origins, directions, t_min, t_max)
    accel = ra.build(scene, method, **options)
    hits = accel.intersect(origins, directions, t_min, t_max, counters=True)
    assert_same_hits(reference, hits)
    np.testing.assert_array_equal(accel.occluded(origins, directions, t_min, t_max), reference.prim >= 0)
    counters = hits.counters
    assert (counters.nodes >= 0).all() and (counters.tests >= 0).all() and (counters.mailbox_skips >= 0).all()
    assert (counters.tests[reference.prim >= 0] >= 1).all()


@pytest.mark.parametrize("variant", VARIANTS, ids=repr)
def test_a_scene_of_one_point_far_from_the_origin_builds_and_agrees_with_brute_force(variant):
    """One degenerate triangle, its three corners one vertex at y = 3e20 (a scene the generator
    found): the uniform grid's box around it, padded by 1e-12 of nothing, had no size at that
    magnitude, and its build crashed on a NaN resolution."""
    mesh = ra.TriangleMesh([[0.0, 3e20, 0.0], [2e20, 0.0, 3e20]], [[0, 0, 0]])
    origins = np.array([[0.0, 0.0, 0.0], [0.0, 4e20, 0.0], [1e20, 3e20, 1e20]])
    directions = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [-1.0, 0.0, -1.0]])
    _check(mesh, origins, directions, np.zeros(3), np.full(3, np.inf), variant)


def triangle_scene_rays(draw, lattice, faces, n):
    """``n`` rays in the lattice coordinates of a :func:`triangle_scenes` scene: from its vertices,
    edge midpoints, centroids or points around it, three in four along lattice directions (through
    vertices and edges, parallel to faces), the others along random ones."""
    corners = lattice[faces]
    candidates = np.concatenate((lattice, 0.5 * (corners[:, 0] + corners[:, 1]), corners.mean(axis=1),
                                 np.array([[-1.0, -1.0, -1.0], [4.0, 4.0, 4.0], [1.5, 1.5, -1.0]])))
    origins, steps = _lattice_rays(draw, candidates, n)
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    return origins, np.where(rng.random((n, 1)) < 0.75, steps, rng.normal(size=(n, 3)))


@settings(max_examples=examples(60), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), variant=st.sampled_from(VARIANTS))
def test_generated_triangle_scenes_agree_with_brute_force(data, variant):
    mesh, to_world, lattice, faces = data.draw(triangle_scenes())
    n = 24
    origins, directions = triangle_scene_rays(data.draw, lattice, faces, n)
    t_min, t_max = _limits(data.draw, n)
    world = to_world(origins)
    world_directions = to_world(directions) - to_world(np.zeros(3))
    assume_nonzero = np.abs(world_directions).sum(axis=1) > 0
    _check(mesh, world[assume_nonzero], world_directions[assume_nonzero], t_min[assume_nonzero],
           t_max[assume_nonzero], variant)


@settings(max_examples=examples(30), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), variant=st.sampled_from(VARIANTS))
def test_generated_sphere_scenes_agree_with_brute_force(data, variant):
    spheres, scale = data.draw(sphere_scenes())
    surface = spheres.centers + spheres.radii[:, None] * np.array([1.0, 0.0, 0.0])
    candidates = np.concatenate((spheres.centers, surface, scale * np.array([[-2.0, -2.0, -2.0], [5.0, 1.0, 1.0]])))
    origins, steps = _lattice_rays(data.draw, candidates, 20)
    t_min, t_max = _limits(data.draw, 20)
    _check(spheres, origins, scale * steps, t_min, t_max, variant)


@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: f"{v[0]}{v[1] or ''}")
def test_every_variant_builds_over_one_degenerate_triangle(variant):
    mesh = ra.TriangleMesh([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]], [[0, 1, 2]])
    _check(mesh, np.array([[0.5, 0.5, 0.5], [-1.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0]]),
           np.zeros(2), np.full(2, np.inf), variant)
