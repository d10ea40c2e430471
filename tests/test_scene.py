"""Mesh loading in every supported format, gzip, trimesh objects, and the sphere scene."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
import trimesh

import rayaccel as ra


@pytest.mark.parametrize("suffix", ["obj", "ply", "stl", "off"])
@pytest.mark.parametrize("compressed", [False, True])
def test_formats_round_trip(tmp_path, suffix, compressed):
    source = trimesh.creation.icosphere(subdivisions=2)
    data = source.export(file_type=suffix)
    data = data.encode() if isinstance(data, str) else data
    path = tmp_path / f"ball.{suffix}{'.gz' if compressed else ''}"
    path.write_bytes(gzip.compress(data) if compressed else data)
    mesh = ra.load_mesh(path)
    assert len(mesh) == len(source.faces)
    np.testing.assert_allclose(mesh.geometry.reshape(-1, 3, 3).mean(axis=(0, 1)), 0.0, atol=1e-2)


def test_trimesh_object_and_build_accepts_it():
    source = trimesh.creation.box()
    mesh = ra.load_mesh(source)
    assert len(mesh) == 12
    accel = ra.build(source, "grid")
    assert accel.intersect([[0, 0, -5.0]], [[0, 0, 1.0]]).t[0] == pytest.approx(4.5)


def test_shipped_meshes_load():
    for name, triangles in [("bunny", 69451), ("dragon-11k", 11102), ("teapot", 6320), ("cornell-box", 36)]:
        assert len(ra.load_scene(name)) >= 0.95 * triangles


def test_random_spheres_keep_the_covered_fraction():
    for n in (10, 1000, 100000):
        balls = ra.random_spheres(n, seed=1)
        volume = (4 / 3 * np.pi * balls.radii**3).sum()
        assert volume == pytest.approx(0.05)
        assert (balls.centers - balls.radii[:, None] >= 0).all()
        assert (balls.centers + balls.radii[:, None] <= 1).all()
    np.testing.assert_array_equal(ra.random_spheres(50, seed=3).centers, ra.load_scene("spheres:50:3").centers)


def test_procedural_forest_scenes():
    forest = ra.load_scene("forest")
    assert 19_000 <= len(forest) <= 21_000
    large, small = ra.load_scene("forest-large-chair"), ra.load_scene("forest-small-chair")
    assert len(large) == len(small) > len(forest) + 30_000
    def chair_extent(scene):
        return np.ptp(scene.vertices[len(forest.vertices):], axis=0)

    assert chair_extent(large).max() > 25 and chair_extent(small).max() < 1
    b = forest.bounds()
    assert b.scene_hi[1] - b.scene_lo[1] < 10  # y is up, the forest is flat
    assert "forest-small-chair" in ra.builtin_scenes()
