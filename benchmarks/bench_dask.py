"""Ray batches over Dask on one machine: what the cluster path costs against a local numpy call.

16,777,216 incoherent rays (origins uniform in the scene box, directions uniform on the sphere) on the
full dragon, ``bvh-binned``. The rays are generated in blocks of 65,536 from a seed per block, so every
configuration traces exactly the same rays. Configurations:

- ``local``: one ``accel.intersect`` call on numpy arrays (Numba on all cores);
- ``threads``: Dask arrays of those numpy arrays on the threaded scheduler;
- ``2x1`` and ``1x2``: a ``LocalCluster`` of 2 worker processes with 1 thread each, and of 1 process
  with 2 threads; the rays are generated on the workers and held in their memory before the clock
  starts, as the results are after it stops (``persist``), as the local call's are.

Each Dask configuration runs with Numba's threads matched to the worker's (``kernel_threads="match"``)
over a sweep of chunk sizes, and without the matching (``None``: every task on all of Numba's threads)
at the largest chunk size. Rounds are interleaved; the medians are printed, with the per-task
overhead fitted as the slope of the wall time over the number of tasks, and the one-off cost of
scattering the structure to the workers.

    PYTHONPATH=src python benchmarks/bench_dask.py [--rays N] [--rounds R]
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import pickle
import statistics
import time

import dask
import dask.array as da
import numpy as np
from distributed import Client, LocalCluster, wait

import rayaccel as ra
from rayaccel import distributed as rd

BLOCK = 65_536


def ray_block(lo, hi, seed, block):
    """Rays ``block * BLOCK`` ... as an (BLOCK, 6) array: origin, unit direction."""
    rng = np.random.default_rng([seed, block])
    origins = rng.uniform(lo, hi, size=(BLOCK, 3))
    directions = rng.normal(size=(BLOCK, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return np.hstack([origins, directions])


def chunk_of_rays(lo, hi, seed, chunk, block_info=None):
    start = block_info[None]["array-location"][0][0]
    return np.vstack([ray_block(lo, hi, seed, b) for b in range(start // BLOCK, start // BLOCK + chunk // BLOCK)])


def dask_rays(lo, hi, seed, n, chunk):
    rays = da.map_blocks(chunk_of_rays, lo, hi, seed, chunk, chunks=((chunk,) * (n // chunk), (6,)),
                         dtype=np.float64, meta=np.empty((0, 6)))
    return rays[:, :3], rays[:, 3:]


def timed_query(accel, origins, directions, kernel_threads, scheduler=None):
    hits = rd.intersect(accel, origins, directions, kernel_threads=kernel_threads)
    start = time.perf_counter()
    kept = dask.persist(hits.t, hits.prim, hits.u, hits.v, scheduler=scheduler)
    if scheduler is None:
        wait(kept)
    seconds = time.perf_counter() - start
    return seconds, int((kept[1] >= 0).sum().compute(scheduler=scheduler))


def task_overhead(accel, origins, directions, client=None, rays=2 ** 18, small=256, rounds=3):
    """Seconds of wall time per task: the same rays traced as given (no reordering, so that the chunk size
    does not change the tracing) in chunks of ``small`` rays and in one chunk per thread, compared."""
    scheduler = None if client is not None else "threads"
    threads = sum(client.nthreads().values()) if client is not None else 2
    timings = {small: [], rays // threads: []}
    for _ in range(rounds):
        for chunk in timings:
            o = da.from_array(origins[:rays], chunks=(chunk, 3))
            d = da.from_array(directions[:rays], chunks=(chunk, 3))
            if client is not None:
                o, d = client.persist([o, d])
                wait([o, d])
            hits = rd.intersect(accel, o, d, reorder=False)
            start = time.perf_counter()
            kept = dask.persist(hits.t, hits.prim, hits.u, hits.v, scheduler=scheduler)
            if client is not None:
                wait(kept)
            timings[chunk].append(time.perf_counter() - start)
    small_s, large_s = (statistics.median(v) for v in timings.values())
    return (small_s - large_s) / (rays // small - threads), small_s, large_s


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--rays", type=int, default=16_777_216)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--chunks", type=int, nargs="+", default=[2 ** 16, 2 ** 18, 2 ** 20, 2 ** 22])
    parser.add_argument("--scene", default="dragon")
    parser.add_argument("--overhead-only", action="store_true", help="only the per-task overhead")
    args = parser.parse_args()
    logging.getLogger("distributed").setLevel(logging.ERROR)
    print(f"load average before: {os.getloadavg()[0]:.1f}", flush=True)
    n = args.rays // BLOCK * BLOCK
    chunks = [c for c in args.chunks if c % BLOCK == 0 and c <= n]
    scene = ra.load_scene(args.scene)
    accel = ra.build(scene, "bvh-binned")
    lo, hi = accel.scene_box
    print(f"{args.scene}: {len(scene):,} triangles, bvh-binned built in {accel.build_seconds:.2f} s; "
          f"{n:,} incoherent rays; structure pickles to {len(pickle.dumps(accel, protocol=5)) / 1e6:.0f} MB")
    rays = np.vstack([ray_block(lo, hi, 0, b) for b in range(n // BLOCK)])
    origins, directions = rays[:, :3], rays[:, 3:]
    warm = accel.intersect(origins[:BLOCK], directions[:BLOCK])
    reference_hits = None

    clusters = {}
    for label, workers, threads in (("2x1", 2, 1), ("1x2", 1, 2)):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        client = Client(cluster, set_as_default=False)
        start = time.perf_counter()
        rd.ship(accel, client)
        send = time.perf_counter() - start
        with client.as_current():
            o, d = dask_rays(lo, hi, 0, 4 * BLOCK, BLOCK)
            rd.intersect(accel, o, d).t.compute()
        clusters[label] = (cluster, client, send)
        print(f"{label}: structure scattered to {workers} worker(s) in {send:.2f} s (one-off)")

    for label, client in [("threads", None)] + [(k, v[1]) for k, v in clusters.items()]:
        context = client.as_current() if client is not None else contextlib.nullcontext()
        with context:
            per_task, small_s, large_s = task_overhead(accel, origins, directions, client)
        print(f"{label}: {per_task * 1e3:.2f} ms of wall time per task (2^18 rays in 1,024 tasks {small_s:.2f} s, "
              f"in one per thread {large_s:.2f} s; 5 tasks per chunk: the query, then t, prim, u, v)", flush=True)
    if args.overhead_only:
        return
    times = {}

    def record(key, seconds, n_hits):
        nonlocal reference_hits
        times.setdefault(key, []).append(seconds)
        print(f"  {key}: {seconds:.2f} s", flush=True)
        if reference_hits is not None and n_hits is not None and n_hits != reference_hits:
            raise AssertionError(f"{key}: {n_hits} hits, local {reference_hits}")

    for round_ in range(args.rounds):
        start = time.perf_counter()
        hits = accel.intersect(origins, directions)
        record(("local", None, "numba"), time.perf_counter() - start, None)
        reference_hits = int(hits.hit.sum())
        del hits
        for chunk in chunks:
            do, dd = da.from_array(origins, chunks=(chunk, 3)), da.from_array(directions, chunks=(chunk, 3))
            modes = ["match", None] if chunk == chunks[-1] else ["match"]
            for mode in modes:
                record(("threads", chunk, mode), *timed_query(accel, do, dd, mode, scheduler="threads"))
            for label, (_, client, _) in clusters.items():
                with client.as_current():
                    co, cd = dask.persist(*dask_rays(lo, hi, 0, n, chunk))
                    wait([co, cd])
                    for mode in modes:
                        record((label, chunk, mode), *timed_query(accel, co, cd, mode))
                    del co, cd
        print(f"round {round_ + 1}/{args.rounds} done", flush=True)

    local = statistics.median(times[("local", None, "numba")])
    print(f"\nlocal numpy call: {local:.2f} s, {n / local / 1e6:.2f} Mrays/s (medians of {args.rounds} rounds)\n")
    print("| config | Numba threads | rays per task | tasks | seconds | Mrays/s | x local |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for (label, chunk, mode), values in times.items():
        if label == "local":
            continue
        seconds = statistics.median(values)
        print(f"| {label} | {'matched' if mode else 'all per task'} | {chunk:,} | {n // chunk} | {seconds:.2f} | "
              f"{n / seconds / 1e6:.2f} | {local / seconds:.2f} |")
    print()
    for label in ("threads", "2x1", "1x2"):
        tasks = np.array([n // c for c in chunks], float)
        seconds = np.array([statistics.median(times[(label, c, "match")]) for c in chunks])
        slope, intercept = np.polyfit(tasks, seconds, 1)
        best = chunks[int(np.argmin(seconds))]
        print(f"{label}: best {best:,} rays per task; wall time = {intercept:.2f} s + {slope * 1e3:.2f} ms per task "
              f"(fit over {len(chunks)} chunk sizes)")
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    for cluster, client, _ in clusters.values():
        client.close()
        cluster.close()
    del warm


if __name__ == "__main__":
    main()
