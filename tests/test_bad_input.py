"""Bad input gets a clear exception naming the problem."""

from __future__ import annotations

import gzip

import numba
import numpy as np
import pytest

import rayaccel as ra
from rayaccel._validate import unusable_ray, unusable_rays

TRIANGLE = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


@pytest.mark.parametrize(
    "vertices, faces, error, words",
    [
        ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], ValueError, "NaN or infinite"),
        ([[0, 0, np.inf], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], ValueError, "NaN or infinite"),
        ([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]], ValueError, "shape"),
        (TRIANGLE, [[0, 1, 3]], ValueError, "out of range"),
        (TRIANGLE, [[0, 1, -1]], ValueError, "out of range"),
        (TRIANGLE, np.zeros((0, 3), int), ValueError, "empty"),
        (np.zeros((0, 3)), [[0, 1, 2]], ValueError, "empty"),
        (TRIANGLE, [[0, 1.5, 2]], TypeError, "integer"),
        (np.array([["a", "b", "c"]] * 3), [[0, 1, 2]], TypeError, "real numbers"),
        (TRIANGLE, [[0, 1, 2, 0]], ValueError, "shape"),
    ],
)
def test_bad_meshes(vertices, faces, error, words):
    with pytest.raises(error, match=words):
        ra.TriangleMesh(vertices, faces)


@pytest.mark.parametrize(
    "centers, radii, words",
    [
        ([[0, 0, 0]], [-1.0], "positive"),
        ([[0, 0, 0]], [0.0], "positive"),
        ([[0, 0, 0]], [np.nan], "NaN"),
        ([[0, 0, np.nan]], [1.0], "NaN"),
        ([[0, 0, 0]], [1.0, 2.0], "shape"),
        (np.zeros((0, 3)), [], "empty"),
    ],
)
def test_bad_spheres(centers, radii, words):
    with pytest.raises(ValueError, match=words):
        ra.Spheres(centers, radii)


def test_random_spheres_arguments():
    with pytest.raises(ValueError, match="at least 1"):
        ra.random_spheres(0)
    with pytest.raises(TypeError):
        ra.random_spheres(2.5)
    with pytest.raises(ValueError, match="fill"):
        ra.random_spheres(10, fill=1.5)


@pytest.fixture(scope="module")
def accel():
    return ra.build(ra.TriangleMesh(TRIANGLE, [[0, 1, 2]]), "grid")


@pytest.mark.parametrize(
    "origins, directions, kwargs, error, words",
    [
        ([[0, 0, -1]], [[0, 0, 0]], {}, ValueError, "zero length"),
        ([[0, 0, np.nan]], [[0, 0, 1]], {}, ValueError, "NaN"),
        ([[0, 0, -1]], [[0, 0, np.inf]], {}, ValueError, "infinite"),
        ([[0, 0, -1], [0, 0, -1]], [[0, 0, 1]] * 3, {}, ValueError, "same shape"),
        ([[0, 0]], [[0, 1]], {}, ValueError, "shape"),
        ([[0, 0, -1]], [[0, 0, 1]], {"t_min": np.nan}, ValueError, "t_min contains NaN"),
        ([[0, 0, -1]], [[0, 0, 1]], {"t_max": [1.0, 2.0]}, ValueError, "t_max must be"),
        ([["x", "y", "z"]], [[0, 0, 1]], {}, TypeError, "real numbers"),
    ],
)
def test_bad_rays(accel, origins, directions, kwargs, error, words):
    with pytest.raises(error, match=words):
        accel.intersect(origins, directions, **kwargs)


def test_empty_ray_batch_and_single_origin(accel):
    hits = accel.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    assert hits.t.shape == (0,)
    hits = accel.intersect([0.2, 0.2, -1.0], [[0, 0, 1.0], [0, 0, -1.0]])
    assert hits.prim.tolist() == [0, -1]


def test_bad_build_arguments():
    mesh = ra.TriangleMesh(TRIANGLE, [[0, 1, 2]])
    with pytest.raises(ValueError, match="unknown method"):
        ra.build(mesh, "bsp")
    with pytest.raises(TypeError):
        ra.build(mesh, "grid", dense=3)
    with pytest.raises(ValueError, match="insert"):
        ra.build(mesh, "grid", insert="fuzzy")
    with pytest.raises(ValueError, match="density"):
        ra.build(mesh, "grid", density=-1)
    with pytest.raises(ValueError, match="resolution"):
        ra.build(mesh, "grid", resolution=(0, 2, 2))
    with pytest.raises(ValueError, match="resolution"):
        ra.build(mesh, "grid", resolution="fine")
    with pytest.raises(TypeError, match="scene"):
        ra.build(np.zeros((3, 3)), "grid")


def test_unreadable_files(tmp_path):
    with pytest.raises(ra.MeshLoadError, match="not found"):
        ra.load_mesh(tmp_path / "missing.obj")
    truncated = tmp_path / "bunny.obj.gz"
    truncated.write_bytes(gzip.compress(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" * 100)[:60])
    with pytest.raises(ra.MeshLoadError, match="cannot read"):
        ra.load_mesh(truncated)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\n"
                        b"end_header\n\x00\x01")
    with pytest.raises(ra.MeshLoadError):
        ra.load_mesh(garbage)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(ra.MeshLoadError, match="no triangles"):
        ra.load_mesh(empty)
    bad_index = tmp_path / "bad.off"
    bad_index.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(ra.MeshLoadError):
        ra.load_mesh(bad_index)
    with pytest.raises(ra.MeshLoadError, match="unsupported"):
        ra.load_mesh(tmp_path / "x.fbx") if (tmp_path / "x.fbx").write_text("x") else None
    with pytest.raises(TypeError):
        ra.load_mesh(42)
    with pytest.raises(ValueError, match="unknown scene"):
        ra.load_scene("no-such-scene")


@pytest.mark.parametrize(
    "vertices, faces, error, words",
    [
        (np.float64(1.0), [[0, 1, 2]], ValueError, "shape"),
        (np.zeros((1, 1, 3, 3)), [[0, 1, 2]], ValueError, "shape"),
        (TRIANGLE.astype(object), [[0, 1, 2]], TypeError, "real numbers"),
        (TRIANGLE, np.array([[0, 1, 2**40]]), ValueError, "out of range"),
        (TRIANGLE, np.array([[0, 1, 2**63 + 5]], dtype=np.uint64), ValueError, "out of range"),
        (TRIANGLE, np.int64(0), ValueError, "shape"),
    ],
)
def test_hostile_meshes(vertices, faces, error, words):
    with pytest.raises(error, match=words):
        ra.TriangleMesh(vertices, faces)


@pytest.mark.parametrize(
    "origins, directions, error, words",
    [
        (np.float64(0.0), [[0, 0, 1.0]], ValueError, "shape"),
        (np.zeros((1, 1, 1, 3)), [[0, 0, 1.0]], ValueError, "shape"),
        (np.array([[0.2, 0.2, -1.0]], dtype=object), [[0, 0, 1.0]], TypeError, "real numbers"),
    ],
)
def test_hostile_rays(accel, origins, directions, error, words):
    with pytest.raises(error, match=words):
        accel.intersect(origins, directions)


def test_read_only_and_strided_inputs_give_the_contiguous_answer():
    rng = np.random.default_rng(0)
    vertices = rng.random((40, 3))
    faces = rng.integers(0, 40, (30, 3))
    origins, directions = rng.random((50, 3)) - 1.0, rng.normal(size=(50, 3))
    expected = ra.build(ra.TriangleMesh(vertices, faces), "bvh-binned").intersect(origins, directions)

    def read_only(a):
        a = a.copy()
        a.setflags(write=False)
        return a

    def strided(a):
        wide = np.zeros((2 * a.shape[0], *a.shape[1:]), dtype=a.dtype)
        wide[::2] = a
        return wide[::2]

    def big_endian(a):
        return a.astype(a.dtype.newbyteorder(">"))

    def subclass(a):
        return a.view(np.matrix) if a.ndim == 2 else a

    for variant in (read_only, strided, np.asfortranarray, big_endian, subclass):
        mesh = ra.TriangleMesh(variant(vertices), variant(faces))
        hits = ra.build(mesh, "bvh-binned").intersect(variant(origins), variant(directions),
                                                      t_min=variant(np.zeros(50)))
        np.testing.assert_array_equal(hits.prim, expected.prim)
        np.testing.assert_array_equal(hits.t, expected.t)


def test_a_build_larger_than_the_free_memory_is_refused_before_it_starts(monkeypatch):
    import rayaccel._memory as memory

    monkeypatch.setattr(memory, "available_bytes", lambda: 10_000)
    mesh = ra.TriangleMesh(np.random.default_rng(0).random((300, 3)), np.arange(300).reshape(100, 3))
    for method in ("bvh-binned", "kdtree", "grid"):
        with pytest.raises(MemoryError, match=r"building '.+' over 100 primitives needs about .* GiB"):
            ra.build(mesh, method)
    scene = ra.Scene()
    scene.add(mesh)
    with pytest.raises(MemoryError, match="GiB"):
        ra.build(scene, "bvh-binned")


@numba.njit(cache=False)
def _unusable_in_lanes_and_alone(origins, directions, first, end):
    alone = 0
    for i in range(first, end):
        alone += unusable_ray(origins[i, 0], origins[i, 1], origins[i, 2], directions[i, 0], directions[i, 1],
                              directions[i, 2])
    return unusable_rays(origins, directions, first, end), alone


@pytest.mark.parametrize("layout", ["float64", "float32", "fortran"])
def test_the_walks_ray_check_counts_each_unusable_ray_once(layout):
    """The check the walks run on a span of rays, eight at a time in vector lanes on contiguous
    arrays, counts exactly the rays that the check of one ray refuses: NaN and infinite
    coordinates anywhere, all-zero directions of either sign, and not tiny or huge ones."""
    rng = np.random.default_rng(4)
    planted = [np.nan, np.inf, -np.inf, 0.0, -0.0, 1e-320, 1e308]
    found = 0
    for _ in range(400):
        n = int(rng.integers(0, 40))
        origins, directions = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        for _ in range(int(rng.integers(0, 6)) if n else 0):
            array = origins if rng.random() < 0.5 else directions
            array[rng.integers(0, n), rng.integers(0, 3)] = rng.choice(planted)
            if rng.random() < 0.3:
                directions[rng.integers(0, n)] = rng.choice([0.0, -0.0], 3)
        if layout == "float32":
            with np.errstate(over="ignore"):
                origins, directions = origins.astype(np.float32), directions.astype(np.float32)
        elif layout == "fortran":
            origins, directions = np.asfortranarray(origins), np.asfortranarray(directions)
        first = int(rng.integers(0, n + 1))
        end = int(rng.integers(first, n + 1))
        in_lanes, alone = _unusable_in_lanes_and_alone(origins, directions, first, end)
        assert in_lanes == alone
        found += alone
    assert found > 100
