"""Scenes of objects and instances: hits against the same geometry baked into the world and brute-forced."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_same_hits, camera_rays, random_rays

import rayaccel as ra


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _affine(linear, translation):
    matrix = np.eye(4)
    matrix[:3, :3] = linear
    matrix[:3, 3] = translation
    return matrix


SHEAR = np.array([[1, 0.3, 0], [0, 1, 0.2], [0, 0, 1]])
SHEARED = _affine(_rotation([1, 2, 3], 0.7) @ np.diag([1.5, 0.6, 2.0]) @ SHEAR, [0.04, -0.02, 0.03])
SIMILAR = _affine(0.4 * _rotation([0, 1, 0], 1.1), [-0.05, 0.01, 0.02])


@pytest.fixture(scope="module")
def mesh_scene(small_dragon):
    scene = ra.Scene()
    scene.add(small_dragon)
    scene.add(small_dragon, transform=SHEARED)
    scene.add(small_dragon, transform=SIMILAR)
    return scene


@pytest.fixture(scope="module")
def mesh_rays(mesh_scene):
    o1, d1 = random_rays(mesh_scene, 1500, seed=3)
    o2, d2 = camera_rays(mesh_scene, 24)
    return np.concatenate((o1, o2)), np.concatenate((d1, d2))


def _world_reference(scene, origins, directions):
    """Brute force over the flattened scene, with (geom, prim) recovered from the flat index."""
    flat = ra.build(scene.flatten(), "none").intersect(origins, directions)
    sizes = np.array([len(scene.objects[o]) for o in scene.instance_object])
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    geom = np.where(flat.prim >= 0, np.searchsorted(starts, flat.prim, side="right") - 1, -1)
    prim = np.where(flat.prim >= 0, flat.prim - starts[np.maximum(geom, 0)], -1)
    return flat, geom, prim


def test_instances_match_the_baked_world(mesh_scene, mesh_rays):
    hits = ra.build(mesh_scene, "bvh-binned").intersect(*mesh_rays)
    flat, geom, prim = _world_reference(mesh_scene, *mesh_rays)
    same = (hits.geom == geom) & (hits.prim == prim)
    assert hits.hit.sum() > 150
    # rounding of the transforms may move a hit across a shared edge: a few rays in 10^4
    assert same.mean() > 0.998
    both = same & (prim >= 0)
    np.testing.assert_allclose(hits.t[both], flat.t[both], rtol=1e-9)
    assert (hits.hit == flat.hit).mean() > 0.999


@pytest.mark.parametrize("method", [m for m in ra.methods() if m != "none"])
def test_every_method_below_agrees_with_brute_force_below(method, mesh_scene, mesh_rays):
    reference = ra.build(mesh_scene, "none").intersect(*mesh_rays)
    hits = ra.build(mesh_scene, method).intersect(*mesh_rays)
    assert_same_hits(reference, hits)
    np.testing.assert_array_equal(hits.geom, reference.geom)
    np.testing.assert_array_equal(ra.build(mesh_scene, method).occluded(*mesh_rays), reference.hit)


def test_identity_instance_is_the_plain_mesh(small_dragon):
    scene = ra.Scene()
    assert scene.add(small_dragon) == 0
    origins, directions = random_rays(small_dragon, 2000, seed=5)
    plain = ra.build(small_dragon, "bvh-binned").intersect(origins, directions)
    hits = ra.build(scene, "bvh-binned").intersect(origins, directions)
    assert_same_hits(plain, hits)
    np.testing.assert_array_equal(hits.geom, plain.geom)
    np.testing.assert_array_equal(plain.geom, np.where(plain.hit, 0, -1))


def test_mixed_meshes_and_spheres(small_dragon):
    balls = ra.random_spheres(200, seed=2)
    scene = ra.Scene()
    scene.add(small_dragon)
    scene.add(balls, transform=SIMILAR)
    scene.add(balls, transform=_affine(0.3 * _rotation([1, 0, 1], 0.4), [0.03, -0.01, -0.02]))
    origins, directions = random_rays(scene, 3000, seed=8)
    hits = ra.build(scene, "bvh-binned").intersect(origins, directions)
    reference = ra.build(scene, "none").intersect(origins, directions)
    assert_same_hits(reference, hits)
    assert set(np.unique(hits.geom)) == {-1, 0, 1, 2}
    # the spheres, baked: same distances, same spheres
    baked = [ra.Spheres(balls.centers @ scene.transform(g)[:3, :3].T + scene.transform(g)[:3, 3],
                        balls.radii * np.cbrt(np.linalg.det(scene.transform(g)[:3, :3]))) for g in (1, 2)]
    for g, world in zip((1, 2), baked):
        mine = hits.geom == g
        alone = ra.build(world, "none").intersect(origins[mine], directions[mine])
        np.testing.assert_array_equal(alone.prim, hits.prim[mine])
        np.testing.assert_allclose(alone.t, hits.t[mine], rtol=1e-9)
    assert np.isnan(hits.u[~hits.hit]).all() and not np.isnan(hits.u[hits.hit]).any()


def test_t_is_in_units_of_the_given_direction(mesh_scene, mesh_rays):
    accel = ra.build(mesh_scene, "bvh-lbvh")
    origins, directions = mesh_rays
    hits = accel.intersect(origins, directions)
    scaled = accel.intersect(origins, 4.0 * directions)
    np.testing.assert_array_equal(scaled.geom, hits.geom)
    np.testing.assert_allclose(scaled.t[hits.hit] * 4.0, hits.t[hits.hit], rtol=1e-9)
    interval = accel.intersect(origins, directions, t_max=np.where(hits.hit, 0.5 * hits.t, np.inf))
    assert not interval.hit[hits.hit].any() or (interval.t[interval.hit] <= 0.5 * hits.t[interval.hit]).all()


def test_counters_add_both_levels(mesh_scene, mesh_rays):
    hits = ra.build(mesh_scene, "bvh-binned").intersect(*mesh_rays, counters=True)
    assert (hits.counters.nodes >= 1).all()
    assert hits.counters.tests[hits.hit].min() >= 1


def test_moving_instances_and_refit(small_dragon):
    scene = ra.Scene()
    scene.add(small_dragon)
    gid = scene.add(small_dragon, transform=SIMILAR)
    accel = ra.build(scene, "bvh-binned")
    origins, directions = random_rays(scene, 2000, seed=4)
    moved = _affine(0.5 * _rotation([0, 0, 1], 2.0), [0.01, 0.04, -0.03])
    scene.set_transform(gid, moved)
    accel.refit()
    fresh = ra.build(scene, "none").intersect(origins, directions)
    assert_same_hits(fresh, accel.intersect(origins, directions))
    stats = accel.stats()
    assert stats["top_sah_cost"] > 0 and stats["top_sah_cost_at_build"] > 0
    assert stats["instances"] == 2 and stats["objects"] == 1
    with pytest.raises(TypeError):
        accel.refit(small_dragon.vertices)


def test_instances_share_one_structure(small_dragon):
    scene = ra.Scene()
    for k in range(50):
        scene.add(small_dragon, transform=_affine(np.eye(3), [k * 0.3, 0.0, 0.0]))
    accel = ra.build(scene, "bvh-binned")
    stats = accel.stats()
    assert stats["objects"] == 1 and stats["instances"] == 50 and stats["primitives"] == 50 * len(small_dragon)
    one = ra.build(small_dragon, "bvh-binned").stats()["bytes"]
    assert stats["bytes"] < 1.2 * one


def test_bad_scenes_and_transforms(small_dragon):
    scene = ra.Scene()
    with pytest.raises(ValueError, match="empty"):
        ra.build(scene, "bvh-binned")
    with pytest.raises(ValueError, match="singular"):
        scene.add(small_dragon, transform=np.diag([1.0, 0.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="affine"):
        scene.add(small_dragon, transform=np.ones((4, 4)))
    with pytest.raises(ValueError, match="shape"):
        scene.add(small_dragon, transform=np.eye(3))
    with pytest.raises(ValueError, match="NaN"):
        scene.add(small_dragon, transform=np.full((4, 4), np.nan))
    with pytest.raises(TypeError):
        scene.add("dragon")
    with pytest.raises(IndexError):
        scene.set_transform(3, np.eye(4))
    assert scene.add(small_dragon, transform=np.eye(4)[:3]) == 0


def test_forest_instanced_renders_like_its_flattened_copy(tmp_path):
    from rayaccel.cli import main
    from rayaccel.procedural import forest_instanced
    from rayaccel.render import default_camera, default_lights, render

    scene = forest_instanced(n_trees=300, size=60.0)
    assert scene.n_instances == 302 and len(scene.objects) == 3
    flat_accel = ra.build(scene.flatten(), "bvh-binned")
    camera = default_camera(flat_accel)
    lights = default_lights(flat_accel, camera)
    instanced = render(ra.build(scene, "bvh-binned"), camera, 48, 48, lights)
    flat = render(flat_accel, camera, 48, 48, lights)
    assert instanced.image.std() > 0.02
    differs = np.abs(instanced.image - flat.image).max(axis=2) > 1e-6
    assert differs.mean() < 0.005
    assert main(["--quiet", "stats", "forest-instanced", "--method", "bvh-lbvh"]) == 0
    assert main(["--quiet", "render", "forest-instanced", "--method", "grid", "--size", "16",
                 "--out", str(tmp_path / "f.png")]) == 0


def test_rotated_sphere_instances_flatten_to_spheres():
    angle = 0.7
    rotation = np.eye(4)
    rotation[:3, :3] = [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]]
    rotation[:3, :3] *= 2.0
    rotation[:3, 3] = [1.0, 2.0, 3.0]
    scene = ra.Scene()
    scene.add(ra.Spheres([[1.0, 0.0, 0.0]], [0.5]), transform=rotation)
    flat = scene.flatten()
    np.testing.assert_allclose(flat.radii, [1.0])
    np.testing.assert_allclose(flat.centers, [[1.0 + 2.0 * np.cos(angle), 2.0 + 2.0 * np.sin(angle), 3.0]])
    sheared = rotation.copy()
    sheared[0, 1] += 0.5
    scene.set_transform(0, sheared)
    with pytest.raises(ValueError, match="ellipsoid"):
        scene.flatten()
