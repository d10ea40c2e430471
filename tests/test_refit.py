"""Refit: a BVH moved to new vertex positions gives the hits of a fresh build on the moved mesh."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_same_hits, camera_rays, random_rays

import rayaccel as ra

BVH_METHODS = [m for m in ra.methods() if m.startswith("bvh-")]


def _deformed(mesh, amount=0.15):
    """The mesh twisted about y and bulged: same faces, every vertex moved."""
    v = mesh.vertices
    center = v.mean(axis=0)
    angle = amount * 8.0 * (v[:, 1] - center[1])
    x, z = v[:, 0] - center[0], v[:, 2] - center[2]
    moved = np.column_stack((center[0] + x * np.cos(angle) - z * np.sin(angle), v[:, 1] * (1 + amount),
                             center[2] + x * np.sin(angle) + z * np.cos(angle)))
    return ra.TriangleMesh(moved, mesh.faces)


@pytest.fixture(scope="module")
def deformed(small_dragon):
    return _deformed(small_dragon)


@pytest.fixture(scope="module")
def deformed_rays(deformed):
    o1, d1 = random_rays(deformed, 1500, seed=11)
    o2, d2 = camera_rays(deformed, 24)
    return np.concatenate((o1, o2)), np.concatenate((d1, d2))


@pytest.mark.parametrize("method", BVH_METHODS)
def test_refit_equals_a_fresh_build(method, small_dragon, deformed, deformed_rays):
    accel = ra.build(small_dragon, method)
    accel.refit(deformed.vertices)
    reference = ra.build(deformed, "none").intersect(*deformed_rays)
    assert_same_hits(reference, accel.intersect(*deformed_rays))
    assert_same_hits(ra.build(deformed, method).intersect(*deformed_rays), accel.intersect(*deformed_rays))
    np.testing.assert_array_equal(accel.occluded(*deformed_rays), reference.hit)
    stats = accel.stats()
    assert stats["sah_cost"] != stats["sah_cost_at_build"] > 0


def test_refit_to_float32_vertices_rewrites_the_lanes_in_place(small_dragon, deformed, deformed_rays):
    """Moved vertices that are float32 numbers keep the dragon's triangles in float32 lanes, which
    the refit writes over in place, and the hits are brute force's on the moved mesh."""
    moved = ra.TriangleMesh(deformed.vertices.astype(np.float32), deformed.faces)
    accel = ra.build(small_dragon, "bvh-binned")
    lanes = accel.geometry
    accel.refit(moved.vertices)
    assert accel.geometry is lanes
    reference = ra.build(moved, "none")
    assert_same_hits(reference.intersect(*deformed_rays), accel.intersect(*deformed_rays))
    np.testing.assert_array_equal(accel.count(*deformed_rays), reference.count(*deformed_rays))


@pytest.mark.parametrize("options", [{"bounds": "sphere"}, {"bounds": "kdop"}, {"width": 2}])
def test_refit_other_volumes(options, small_dragon, deformed, deformed_rays):
    accel = ra.build(small_dragon, "bvh-binned", **options)
    accel.refit(deformed.vertices)
    assert_same_hits(ra.build(deformed, "none").intersect(*deformed_rays), accel.intersect(*deformed_rays))


def test_refit_spheres_and_back():
    balls = ra.random_spheres(2000, seed=3)
    accel = ra.build(balls, "bvh-binned")
    moved = balls.centers + 0.05 * np.sin(7.0 * balls.centers[:, [1, 2, 0]])
    accel.refit(moved)
    origins, directions = random_rays(balls, 2000, seed=1)
    assert_same_hits(ra.build(ra.Spheres(moved, balls.radii), "none").intersect(origins, directions),
                     accel.intersect(origins, directions))
    accel.refit(balls.centers)
    assert_same_hits(ra.build(balls, "none").intersect(origins, directions), accel.intersect(origins, directions))


def test_refit_needs_the_same_shape_and_a_bvh(small_dragon):
    accel = ra.build(small_dragon, "bvh-lbvh")
    with pytest.raises(ValueError, match="shape"):
        accel.refit(small_dragon.vertices[:-1])
    with pytest.raises(ValueError, match="NaN"):
        accel.refit(np.full_like(small_dragon.vertices, np.nan))
    for method in ("grid", "kdtree", "none", "grid-bvh", "hgrid", "octree"):
        with pytest.raises(NotImplementedError, match="ra.build"):
            ra.build(ra.random_spheres(50), method).refit(np.zeros((50, 3)))
