"""Queries on Dask arrays and tiled renders on a real two-process LocalCluster: the same bits as numpy.

Dask is installed by the ``test`` extra; these tests fail, not skip, without it.
"""

from __future__ import annotations

import os
import pickle
import signal
import time

import dask
import dask.array as da
import numpy as np
import pytest
from conftest import random_rays
from distributed import Client, LocalCluster

import rayaccel as ra
from rayaccel import distributed as rd
from rayaccel.cli import main
from rayaccel.render import render, save_png


@pytest.fixture(scope="session")
def cluster():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as local, \
            Client(local, set_as_default=False) as client:
        yield local, client


@pytest.fixture
def client(cluster):
    """The session's client, current for this test only (tests without it use the threaded scheduler)."""
    with cluster[1].as_current():
        yield cluster[1]


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def _holds(task, value):
    return task is value or getattr(task, "value", None) is value


def _dependencies(task):
    return getattr(task, "dependencies", ())


def uneven(n, seed):
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, n), 6, replace=False))
    return tuple(np.diff(np.concatenate([[0], cuts, [n]])).tolist())


def test_workers_run_this_checkout(client):
    paths = set(client.run(lambda: __import__("rayaccel").__file__).values())
    assert paths == {ra.__file__}


@pytest.fixture(scope="module", params=["mesh", "spheres"])
def scene(request, bunny, spheres):
    return bunny if request.param == "mesh" else spheres


@pytest.mark.parametrize("method", ["grid", "bvh-binned", "kdtree"])
def test_dask_queries_equal_numpy_bit_for_bit(client, scene, method):
    accel = ra.build(scene, method)
    n = 40_000
    origins, directions = random_rays(scene, n, seed=3)
    rng = np.random.default_rng(4)
    t_min = rng.uniform(0.0, 0.2, n)
    t_max = rng.uniform(0.5, 3.0, n)
    chunks = uneven(n, 5)
    dask_origins = da.from_array(origins, chunks=(chunks, 3))
    dask_directions = da.from_array(directions.astype(np.float64), chunks=(chunks, 3))
    dask_t_max = da.from_array(t_max, chunks=uneven(n, 6))
    hits = accel.intersect(dask_origins, dask_directions, t_min, dask_t_max, counters=True)
    assert all(isinstance(x, da.Array) and x.chunks == (chunks,) for x in (hits.t, hits.prim, hits.u, hits.v))
    blocked = accel.occluded(dask_origins, dask_directions, t_min, dask_t_max)
    got = dask.compute(hits.t, hits.prim, hits.u, hits.v, *hits.counters, blocked)
    want = accel.intersect(origins, directions, t_min, t_max, counters=True)
    for g, w in zip(got, [want.t, want.prim, want.u, want.v, *want.counters,
                          accel.occluded(origins, directions, t_min, t_max)]):
        same_bits(g, w)
    assert (got[1] >= 0).any() and (got[1] < 0).any()


def test_structure_travels_once_per_client(client, spheres):
    accel = ra.build(spheres, "grid")
    first = rd.ship(accel)
    origins, directions = random_rays(spheres, 1000)
    hits = accel.intersect(da.from_array(origins, chunks=100), da.from_array(directions, chunks=100))
    assert rd.ship(accel) is first
    assert len(client.who_has([first])[first.key]) == 2
    graph = dict(hits.t.__dask_graph__())
    assert not any(_holds(task, accel) for task in graph.values())
    assert all(first.key in _dependencies(task) for key, task in graph.items() if "rayaccel-intersect" in str(key))
    same_bits(hits.t.compute(), accel.intersect(origins, directions).t)


def test_threaded_scheduler_without_a_client(spheres):
    accel = ra.build(spheres, "hgrid")
    origins, directions = random_rays(spheres, 5000, seed=9)
    hits = accel.intersect(da.from_array(origins, chunks=700), directions)
    graph = dict(hits.t.__dask_graph__())
    holding = [key for key, task in graph.items() if _holds(task, accel)]
    assert len(holding) == 1
    assert all(holding[0] in _dependencies(task) for key, task in graph.items() if "rayaccel-intersect" in str(key))
    t, prim = dask.compute(hits.t, hits.prim, scheduler="threads")
    want = accel.intersect(origins, directions)
    same_bits(t, want.t)
    same_bits(prim, want.prim)


def test_scene_of_instances_on_the_cluster(client, bunny, spheres):
    scene = ra.Scene()
    scene.add(bunny)
    moved = np.eye(4)
    moved[:3, 3] = [0.3, 0.0, 0.0]
    scene.add(bunny, transform=moved)
    scene.add(spheres)
    accel = ra.build(scene, "bvh-binned")
    origins, directions = random_rays(bunny, 4000, seed=4)
    hits = accel.intersect(da.from_array(origins, chunks=1500), da.from_array(directions, chunks=1500))
    t, prim, geom = dask.compute(hits.t, hits.prim, hits.geom)
    want = accel.intersect(origins, directions)
    assert (want.prim >= 0).any() and len(set(want.geom.tolist())) > 2
    for got, expected in ((t, want.t), (prim, want.prim), (geom, want.geom)):
        same_bits(got, expected)
    same_bits(accel.occluded(da.from_array(origins, chunks=1500), directions).compute(),
              accel.occluded(origins, directions))


def test_single_origin_and_per_ray_limits_as_numpy(spheres):
    accel = ra.build(spheres, "bvh-binned")
    _, directions = random_rays(spheres, 3000, seed=2)
    origin = np.array([0.5, 0.5, 0.5])
    t_min = np.full(3000, 0.01)
    want = accel.occluded(origin, directions, t_min, 0.3)
    got = accel.occluded(origin, da.from_array(directions, chunks=1000), t_min, 0.3)
    assert got.chunks == ((1000, 1000, 1000),)
    same_bits(got.compute(scheduler="sync"), want)
    same_bits(accel.occluded(da.from_array(origin[None]), directions, da.from_array(t_min)).compute(scheduler="sync"),
              accel.occluded(origin, directions, t_min))


def test_dask_input_errors(spheres):
    accel = ra.build(spheres, "grid")
    directions = da.ones((10, 3), chunks=5)
    with pytest.raises(ValueError, match="same shape"):
        accel.intersect(np.zeros((9, 3)), directions)
    with pytest.raises(ValueError, match="t_max"):
        accel.intersect(np.zeros((10, 3)), directions, 0.0, np.ones(7))
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        accel.occluded(np.zeros((10, 3)), da.ones((10, 2), chunks=5))
    with pytest.raises(ValueError, match="unknown chunk sizes"):
        accel.intersect(directions[directions[:, 0] > 0], directions[directions[:, 0] > 0])
    with pytest.raises(ValueError, match="kernel_threads"):
        rd.intersect(accel, directions, directions, kernel_threads=0)
    with pytest.raises(ImportError, match=r'pip install "rayaccel\[dask\]"'):
        rd._require("dask_module_that_does_not_exist")


def test_every_method_pickles_and_answers_alike(small_dragon):
    origins, directions = random_rays(small_dragon, 2000, seed=1)
    for method in ra.methods():
        accel = ra.build(small_dragon, method)
        accel.intersect(origins, directions)
        copy = pickle.loads(pickle.dumps(accel))
        want, got = accel.intersect(origins, directions), copy.intersect(origins, directions)
        for name in ("t", "prim", "u", "v"):
            same_bits(getattr(got, name), getattr(want, name))


def test_each_task_runs_one_kernel_thread_per_worker_thread(client):
    def threads_inside():
        from rayaccel._jit import thread_count

        with rd._kernel_threads("match"):
            inside = thread_count()
        return inside, thread_count()

    inside, after = client.submit(threads_inside, pure=False).result()
    assert inside == 1 and after == ra._jit.max_threads()


def test_tiled_render_equals_the_local_render(client, spheres, tmp_path):
    accel = ra.build(spheres, "grid")
    local = render(accel, width=90, height=150)
    rows = []
    tiled = rd.render(accel, width=90, height=150, tile_rows=64, progress=lambda done, total: rows.append(done))
    for name in ("image", "nodes", "tests"):
        same_bits(getattr(tiled, name), getattr(local, name))
    assert (tiled.primary_rays, tiled.shadow_rays) == (local.primary_rays, local.shadow_rays)
    assert sorted(rows)[-1] == 150 and len(rows) == 3
    tiled_png = save_png(tiled.image, tmp_path / "a.png").read_bytes()
    assert tiled_png == save_png(local.image, tmp_path / "b.png").read_bytes()
    sample = np.random.default_rng(0).choice(90 * 150, 2000, replace=False)
    same_bits(rd.render(accel, width=90, height=150, pixels=sample, tile_rows=64).image,
              render(accel, width=90, height=150, pixels=sample).image)


def test_cli_render_on_a_cluster_writes_the_same_png(cluster, tmp_path):
    args = ["--quiet", "render", "dragon-11k", "--method", "bvh-binned", "--size", "70"]
    assert main(args + ["--out", str(tmp_path / "local.png")]) == 0
    assert main(args + ["--out", str(tmp_path / "cluster.png"), "--scheduler", cluster[0].scheduler_address]) == 0
    assert (tmp_path / "cluster.png").read_bytes() == (tmp_path / "local.png").read_bytes()
    assert main(args + ["--workers", "2", "--scheduler", cluster[0].scheduler_address]) == 2


def test_a_killed_worker_is_retried_and_the_result_is_exact(client, spheres):
    accel = ra.build(spheres, "none")
    origins, directions = random_rays(spheres, 60_000, seed=11)
    want = accel.intersect(origins, directions)
    hits = accel.intersect(da.from_array(origins, chunks=3000), da.from_array(directions, chunks=3000))
    pids = client.run(os.getpid)
    future = client.compute(hits.t)
    deadline = time.monotonic() + 60
    while not any(ts.state == "memory" for ts in _chunk_tasks(client, hits.t)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not future.done()
    os.kill(next(iter(pids.values())), signal.SIGKILL)
    same_bits(future.result(timeout=120), want.t)
    client.wait_for_workers(2, timeout=60)
    assert set(client.run(os.getpid).values()) != set(pids.values())


def _chunk_tasks(client, array):
    names = {key[0] for key in array.__dask_keys__()}
    return [ts for key, ts in client.cluster.scheduler.tasks.items() if isinstance(key, tuple) and key[0] in names]


def test_restart_ships_the_structure_again(client, spheres):
    accel = ra.build(spheres, "grid")
    first = rd.ship(accel)
    client.restart()
    origins, directions = random_rays(spheres, 2000, seed=12)
    hits = accel.intersect(da.from_array(origins, chunks=500), directions)
    assert rd.ship(accel) is not first
    same_bits(hits.prim.compute(), accel.intersect(origins, directions).prim)


def test_grid_vs_none_renders_its_big_rows_on_the_cluster(client, tmp_path):
    from rayaccel.experiments import grid_vs_none

    rows = grid_vs_none.run((10, 1000), image_size=24, client=client, distribute_from=1000)
    assert [row.on_cluster for row in rows] == [False, True]
    table, _ = grid_vs_none.write_report(rows, tmp_path, 24)
    assert "| 1,000 (D) |" in table.read_text() and "Dask cluster" in table.read_text()
    assert main(["--quiet", "experiment", "bvh", "--workers", "2", "--out", str(tmp_path)]) == 2
