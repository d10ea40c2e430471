"""Save, load and pickle: bit-identical results, and damaged or crafted files refused before any kernel runs."""

from __future__ import annotations

import io
import json
import pickle

import numpy as np
import pytest
from conftest import ground_and_clutter, random_rays

import rayaccel as ra
from rayaccel.persist import CorruptFileError, write_members


def _assert_identical(a, b):
    for name in ("t", "prim", "u", "v", "geom"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.fixture(scope="module")
def scenes(small_dragon):
    balls = ra.random_spheres(500, seed=4)
    mixed = ra.Scene()
    mixed.add(small_dragon)
    mixed.add(balls, transform=np.diag([0.1, 0.1, 0.1, 1.0]))
    mixed.add(small_dragon, transform=[[0, -1, 0, 0.05], [1, 0, 0, 0], [0, 0, 1.5, 0.01]])
    return {"mesh": small_dragon, "spheres": balls, "scene": mixed}


CASES = [(m, s) for m in ra.methods() for s in ("mesh", "spheres")] + [
    ("bvh-binned", "scene"), ("kdtree", "scene"), ("grid", "scene")]
OPTIONS = {"bvh-sah": {"bounds": "kdop"}, "bvh-median-space": {"bounds": "sphere"}, "bvh-lbvh": {"width": 2}}


@pytest.mark.parametrize("method,kind", CASES)
def test_save_load_and_pickle_are_bit_identical(method, kind, scenes, tmp_path):
    scene = scenes[kind]
    accel = ra.build(scene, method, **OPTIONS.get(method, {}))
    origins, directions = random_rays(scene, 1200, seed=2)
    expected = accel.intersect(origins, directions, counters=True)
    path = tmp_path / "accel.npz"
    accel.save(path)
    for copy in (ra.load_accelerator(path), pickle.loads(pickle.dumps(accel))):
        assert type(copy) is type(accel) and copy.method == accel.method
        got = copy.intersect(origins, directions, counters=True)
        _assert_identical(expected, got)
        np.testing.assert_array_equal(np.column_stack(got.counters), np.column_stack(expected.counters))
        np.testing.assert_array_equal(copy.occluded(origins, directions), accel.occluded(origins, directions))
        assert copy.build_seconds == accel.build_seconds


def test_refitted_bvh_round_trips(small_dragon, tmp_path):
    accel = ra.build(small_dragon, "bvh-binned")
    accel.refit(small_dragon.vertices * [1.0, 1.3, 1.0])
    accel.save(tmp_path / "a.npz")
    copy = ra.load_accelerator(tmp_path / "a.npz")
    origins, directions = random_rays(small_dragon, 500)
    _assert_identical(accel.intersect(origins, directions), copy.intersect(origins, directions))
    assert copy.stats()["sah_cost_at_build"] == accel.stats()["sah_cost_at_build"]


@pytest.fixture(scope="module")
def saved(tmp_path_factory, small_dragon):
    path = tmp_path_factory.mktemp("saved") / "dragon.npz"
    ra.build(small_dragon, "bvh-binned").save(path)
    return path.read_bytes()


def test_every_flipped_byte_is_refused(saved, tmp_path):
    rng = np.random.default_rng(0)
    positions = np.concatenate((rng.integers(0, len(saved), 200), np.arange(0, 80), np.arange(len(saved) - 200,
                                                                                              len(saved))))
    path = tmp_path / "flipped.npz"
    for position in positions:
        damaged = bytearray(saved)
        damaged[position] ^= 1 << int(rng.integers(0, 8))
        path.write_bytes(bytes(damaged))
        with pytest.raises(CorruptFileError):
            ra.load_accelerator(path)


def test_truncated_files_are_refused(saved, tmp_path):
    path = tmp_path / "short.npz"
    for length in (0, 10, 100, len(saved) // 3, len(saved) // 2, len(saved) - 100, len(saved) - 1):
        path.write_bytes(saved[:length])
        with pytest.raises(CorruptFileError):
            ra.load_accelerator(path)


def _read(data):
    with np.load(io.BytesIO(data)) as npz:
        members = {name: npz[name] for name in npz.files}
    return json.loads(members.pop("__manifest__").tobytes()), members


def _write(path, header, arrays):
    """A well-formed file, checksum and all, holding crafted arrays and state."""
    header["arrays"] = {name: {"dtype": a.dtype.str, "shape": list(a.shape)} for name, a in arrays.items()}
    write_members(path, {"__manifest__": np.frombuffer(json.dumps(header).encode(), np.uint8), **arrays})


def _crafts(arrays):
    n_nodes = len(arrays["bvh.node_first"])
    inner = np.flatnonzero(arrays["bvh.node_count"] == 0)
    leaf = np.flatnonzero(arrays["bvh.node_count"] > 0)

    def changed(name, edit):
        def apply(a):
            a = {k: v.copy() for k, v in a.items()}
            edit(a[name])
            return a
        return apply

    def replaced(name, value):
        return lambda a: {**a, name: value}

    return {
        "child out of bounds": changed("bvh.node_first", lambda f: f.__setitem__(inner[-1], n_nodes)),
        "child before parent (a cycle)": changed("bvh.node_first", lambda f: f.__setitem__(inner[3], 0)),
        "two parents": changed("bvh.node_first", lambda f: f.__setitem__(inner[2], f[inner[1]])),
        "negative count": changed("bvh.node_count", lambda c: c.__setitem__(leaf[0], -5)),
        "leaf past the primitives": changed("bvh.node_first", lambda f: f.__setitem__(leaf[-1], 10 ** 6)),
        "prim order not a permutation": changed("bvh.prim_order", lambda o: o.__setitem__(0, o[1])),
        "prim order out of range": changed("bvh.prim_order", lambda o: o.__setitem__(0, -1)),
        "NaN box": changed("bvh.node_box", lambda b: b.__setitem__((5, 2), np.nan)),
        "inverted box": changed("bvh.node_box", lambda b: b.__setitem__((0, 0), 1e9)),
        "face index out of range": changed("scene.faces", lambda f: f.__setitem__((7, 1), 10 ** 9)),
        "infinite vertex": changed("scene.vertices", lambda v: v.__setitem__((3, 0), np.inf)),
        "wrong dtype": lambda a: {**a, "bvh.node_first": a["bvh.node_first"].astype(np.int64)},
        "wrong shape": lambda a: {**a, "bvh.node_box": a["bvh.node_box"][:, :5].copy()},
        "short count array": lambda a: {**a, "bvh.node_count": a["bvh.node_count"][:-1].copy()},
        "missing array": lambda a: {k: v for k, v in a.items() if k != "bvh.prim_order"},
        "object array": replaced("bvh.prim_order", np.array([1, "x"], dtype=object)),
        "wide slot out of range": changed("bvh.wide_slots", lambda s: s.__setitem__((1, 1), n_nodes)),
        "wide node without children": changed("bvh.wide_slots", lambda s: s.__setitem__((0, 0), -1)),
        "wide child before parent": changed("bvh.wide_children", lambda c: c.__setitem__(_wide_inner(arrays, 3),
                                                                                          0)),
        "wide node with two parents": changed("bvh.wide_children", lambda c: c.__setitem__(
            _wide_inner(arrays, 4), c[_wide_inner(arrays, 5)])),
        "wide children missing": lambda a: {k: v for k, v in a.items() if k != "bvh.wide_children"},
    }


def _wide_inner(arrays, k):
    """The ``k``-th slot of the wide collapse that holds an inner binary node."""
    slots = arrays["bvh.wide_slots"]
    inner = np.argwhere((slots >= 0) & (arrays["bvh.node_count"][np.maximum(slots, 0)] == 0))
    return tuple(inner[k])


@pytest.mark.parametrize("craft", list(_crafts({"bvh.node_first": np.zeros(9, np.int32),
                                               "bvh.node_count": np.zeros(9, np.int32)})))
def test_crafted_files_are_refused(craft, saved, tmp_path):
    header, arrays = _read(saved)
    path = tmp_path / "crafted.npz"
    _write(path, header, _crafts(arrays)[craft](arrays))
    with pytest.raises(CorruptFileError):
        ra.load_accelerator(path)


def test_a_file_without_the_wide_collapse_derives_it(saved, small_dragon, tmp_path):
    header, arrays = _read(saved)
    path = tmp_path / "derived.npz"
    _write(path, header, {k: v for k, v in arrays.items() if not k.startswith("bvh.wide_")})
    (tmp_path / "saved.npz").write_bytes(saved)
    origins, directions = random_rays(small_dragon, 500, seed=3)
    _assert_identical(ra.load_accelerator(path).intersect(origins, directions),
                      ra.load_accelerator(tmp_path / "saved.npz").intersect(origins, directions))


def test_a_file_of_the_four_wide_layout_loads_eight_wide(saved, small_dragon, tmp_path):
    """Files written before the eight-wide layout carry ``width=4`` and a collapse four slots wide:
    the option becomes 8 and the collapse is derived again."""
    header, arrays = _read(saved)
    header["state"]["options"]["width"] = 4
    slots = arrays["bvh.wide_slots"]
    arrays = {**arrays, "bvh.wide_slots": slots[:, :4].copy(), "bvh.wide_children": slots[:, :4].copy()}
    path = tmp_path / "four_wide.npz"
    _write(path, header, arrays)
    (tmp_path / "saved.npz").write_bytes(saved)
    loaded = ra.load_accelerator(path)
    assert loaded.options["width"] == 8
    origins, directions = random_rays(small_dragon, 500, seed=4)
    _assert_identical(loaded.intersect(origins, directions),
                      ra.load_accelerator(tmp_path / "saved.npz").intersect(origins, directions))


@pytest.mark.parametrize("edit", ["version", "format", "method", "bounds", "pad"])
def test_crafted_states_are_refused(edit, saved, tmp_path):
    header, arrays = _read(saved)
    if edit == "version":
        header["version"] = 99
    elif edit == "format":
        header["format"] = "something-else"
    elif edit == "method":
        header["state"]["method"] = "bsp"
    elif edit == "bounds":
        header["state"]["options"]["bounds"] = "cylinder"
    else:
        header["state"]["structure"]["pad"] = "wide"
    _write(tmp_path / "c.npz", header, arrays)
    with pytest.raises(CorruptFileError):
        ra.load_accelerator(tmp_path / "c.npz")


@pytest.mark.parametrize("method", ["grid", "hgrid", "grid-bvh", "kdtree", "octree"])
def test_crafted_links_of_other_structures_are_refused(method, small_dragon, tmp_path):
    ra.build(small_dragon, method).save(tmp_path / "a.npz")
    header, arrays = _read((tmp_path / "a.npz").read_bytes())
    name = {"grid": "grid.cell_prims", "hgrid": "hgrid.cell_child", "grid-bvh": "hybrid.cell_root",
            "kdtree": "kd.node_link", "octree": "octree.node_link"}[method]
    for bad in (-7, 2 ** 30):
        crafted = {k: v.copy() for k, v in arrays.items()}
        crafted[name].reshape(-1)[-2] = bad
        _write(tmp_path / "c.npz", header, crafted)
        with pytest.raises(CorruptFileError):
            ra.load_accelerator(tmp_path / "c.npz")


def test_not_a_file_and_not_an_accelerator(tmp_path):
    with pytest.raises(FileNotFoundError):
        ra.load_accelerator(tmp_path / "missing.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(CorruptFileError):
        ra.load_accelerator(tmp_path / "other.npz")
    (tmp_path / "mesh.obj").write_text("v 0 0 0\n")
    with pytest.raises(CorruptFileError):
        ra.load_accelerator(tmp_path / "mesh.obj")


def test_command_line_builds_saves_and_reads(tmp_path, capsys):
    from rayaccel.cli import main

    saved = tmp_path / "teapot.npz"
    assert main(["--quiet", "build", "teapot", "--method", "bvh-binned", "--out", str(saved)]) == 0
    assert ra.load_accelerator(saved).method == "bvh-binned"
    assert main(["--quiet", "render", str(saved), "--size", "24", "--out", str(tmp_path / "t.png")]) == 0
    assert (tmp_path / "t.png").exists()
    assert main(["--quiet", "stats", str(saved)]) == 0
    assert "sah_cost" in capsys.readouterr().out
    damaged = bytearray(saved.read_bytes())
    damaged[len(damaged) // 2] ^= 4
    saved.write_bytes(bytes(damaged))
    assert main(["--quiet", "stats", str(saved)]) == 2
    assert "checksum" in capsys.readouterr().err


def test_a_kd_tree_keeps_its_primitives_apart_through_a_file(tmp_path):
    scene = ground_and_clutter()
    accel = ra.build(scene, "kdtree")
    origins, directions = random_rays(scene, 1500, seed=5)
    expected = accel.intersect(origins, directions, counters=True)
    accel.save(tmp_path / "a.npz")
    for copy in (ra.load_accelerator(tmp_path / "a.npz"), pickle.loads(pickle.dumps(accel))):
        np.testing.assert_array_equal(copy.apart_prims, [0, 1])
        got = copy.intersect(origins, directions, counters=True)
        _assert_identical(expected, got)
        np.testing.assert_array_equal(np.column_stack(got.counters), np.column_stack(expected.counters))
    header, arrays = _read((tmp_path / "a.npz").read_bytes())
    leaf = int(arrays["kd.leaf_prims"][0])
    for bad in ([0, 0], [0, leaf], [0, len(scene)], [-1]):
        _write(tmp_path / "c.npz", header, {**arrays, "kd.apart_prims": np.array(bad, dtype=np.int64)})
        with pytest.raises(CorruptFileError, match="apart"):
            ra.load_accelerator(tmp_path / "c.npz")
    ra.build(scene, "kdtree", large_apart=False).save(tmp_path / "in.npz")
    header, arrays = _read((tmp_path / "in.npz").read_bytes())
    del header["state"]["options"]["large_apart"]
    _write(tmp_path / "older.npz", header, {k: v for k, v in arrays.items() if k != "kd.apart_prims"})
    older = ra.load_accelerator(tmp_path / "older.npz")
    assert len(older.apart_prims) == 0
    _assert_identical(older.intersect(origins, directions), expected)


def test_a_kd_tree_keeps_its_width_through_a_file(small_dragon, tmp_path):
    """The width a kd-tree is walked at comes back from its file, its cells derived again for width 8
    (:mod:`rayaccel.structures.kdtree.wide_cells`); a file written before the option walks eight-wide
    unless it enters empty leaves (the lecture's tree), and a width the tree cannot take is refused."""
    origins, directions = random_rays(small_dragon, 1500, seed=6)
    for options in ({}, {"width": 2}, {"width": 2, "skip_empty": False}):
        accel = ra.build(small_dragon, "kdtree", **options)
        accel.save(tmp_path / "kd.npz")
        loaded = ra.load_accelerator(tmp_path / "kd.npz")
        assert loaded.options == accel.options
        assert (loaded.cells is None) == (accel.cells is None)
        if accel.cells is not None:
            np.testing.assert_array_equal(loaded.cells.records, accel.cells.records)
        _assert_identical(accel.intersect(origins, directions, counters=True),
                          loaded.intersect(origins, directions, counters=True))
        header, arrays = _read((tmp_path / "kd.npz").read_bytes())
        del header["state"]["options"]["width"]
        _write(tmp_path / "older.npz", header, arrays)
        assert ra.load_accelerator(tmp_path / "older.npz").options["width"] == (2 if "skip_empty" in options else 8)
    for width, skip_empty in ((4, True), (True, True), (8, False)):
        header["state"]["options"].update(width=width, skip_empty=skip_empty)
        _write(tmp_path / "bad.npz", header, arrays)
        with pytest.raises(CorruptFileError, match="width"):
            ra.load_accelerator(tmp_path / "bad.npz")
