"""rayaccel's structures against Embree (embreex) and Open3D, same rays, same run.

For each scene and method: build seconds and closest-hit Mrays/s on primary
(pinhole camera) and incoherent (origins in the scene box, uniform directions)
rays, any-hit Mrays/s on primary rays, and the ratio of each to Embree's on 2
threads (embreex queries run on one thread; the 2-thread figure splits the rays
over two Python threads, as embreex releases the GIL) and, for closest hit, to
the best rayaccel BVH in the run. rayaccel sorts incoherent batches before
tracing them (``rayaccel.ray_order``); the row "rays as given" repeats the
first method with ``reorder=False``, to show what the sort adds. Every figure
is the median of five rounds in which all structures and competitors take
turns, so that all of them meet the same phases of a noisy machine. Brute force is timed on a subset of the rays.
Figures vary by +-30% on a shared machine: read the ratios, not the absolutes.

    python benchmarks/bench_structures.py [--scenes bunny dragon] [--methods grid bvh-binned] [--side 1024]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
from _common import ensure_competitors, incoherent_rays, median_seconds, primary_rays  # noqa: E402

import rayaccel as ra  # noqa: E402

ROUNDS = 5  # timing rounds; each subject's figure is its median


class EmbreeScene:
    """embreex with float32 rays, on one thread or split over several Python threads."""

    def __init__(self, mesh):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        start = time.perf_counter()
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32))
        self.scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # commit (builds the BVH)
        self.build_seconds = time.perf_counter() - start

    def query(self, origins, directions, threads: int, kind: str = "INTERSECT"):
        o = origins.astype(np.float32)
        d = directions.astype(np.float32)
        if threads == 1:
            return self.scene.run(o, d, query=kind)
        parts = np.array_split(np.arange(len(o)), threads)
        with ThreadPoolExecutor(threads) as pool:
            results = list(pool.map(lambda idx: self.scene.run(o[idx], d[idx], query=kind), parts))
        return np.concatenate(results)


class Open3dScene:
    """Open3D's RaycastingScene (Embree inside); its BVH is built on the first query."""

    def __init__(self, mesh):
        import open3d as o3d

        self.o3d = o3d
        start = time.perf_counter()
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                                 o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        self.scene.cast_rays(o3d.core.Tensor(np.array([[0, 0, 0, 1, 1, 1]], np.float32)))
        self.build_seconds = time.perf_counter() - start

    def query(self, origins, directions, threads: int, kind: str = "INTERSECT"):
        rays = self.o3d.core.Tensor(np.hstack([origins, directions]).astype(np.float32))
        if kind == "OCCLUDED":
            return self.scene.test_occlusions(rays, nthreads=threads).numpy()
        return self.scene.cast_rays(rays, nthreads=threads)["primitive_ids"].numpy()


def _queries(intersect, occluded, rays) -> dict:
    """The timed calls of one subject: closest hit on each ray set, any hit on primary rays."""
    calls = {label: (len(o), lambda o=o, d=d: intersect(o, d)) for label, (o, d) in rays.items()}
    o, d = rays["primary"]
    calls["any-hit"] = (len(o), lambda: occluded(o, d))
    return calls


def _interleaved_rates(subjects: list[dict], console: Console) -> None:
    """Mrays/s of every subject's queries, the median of ``ROUNDS`` rounds in which every
    subject runs every query once in turn, so that all of them see the same phases of a
    noisy machine; written into each subject's row."""
    for subject in subjects:
        for _, call in subject["calls"].values():
            call()
    seconds = {(i, label): [] for i, subject in enumerate(subjects) for label in subject["calls"]}
    for round_ in range(ROUNDS):
        console.log(f"round {round_ + 1} of {ROUNDS}")
        for i, subject in enumerate(subjects):
            for label, (_, call) in subject["calls"].items():
                start = time.perf_counter()
                call()
                seconds[i, label].append(time.perf_counter() - start)
    for i, subject in enumerate(subjects):
        for label, (n_rays, _) in subject.pop("calls").items():
            subject[label] = n_rays / float(np.median(seconds[i, label])) / 1e6


def bench_scene(name: str, methods: list[str], side: int, competitors: set[str], console: Console) -> list[dict]:
    scene = ra.load_scene(name)
    rays = {"primary": primary_rays(scene, side), "incoherent": incoherent_rays(scene, side * side)}
    subjects = []
    accels = {}
    for method in methods:
        accel = accels[method] = ra.build(scene, method)
        subjects.append({"scene": name, "method": f"rayaccel {method}",
                         "build": median_seconds(lambda: ra.build(scene, method), repeats=3),
                         "calls": _queries(accel.intersect, accel.occluded, rays)})
    first = accels[methods[0]]
    subjects.append({"scene": name, "method": f"rayaccel {methods[0]}, rays as given", "build": subjects[0]["build"],
                     "calls": _queries(partial(first.intersect, reorder=False), partial(first.occluded, reorder=False),
                                       rays)})
    reference_hits = accel.intersect(*rays["primary"]).prim
    if "embreex" in competitors:
        embree = EmbreeScene(scene)
        agreement = np.mean(embree.query(*rays["primary"], 1) == reference_hits)
        console.print(f"{name}: Embree and rayaccel report the same primitive for {agreement:.2%} of primary rays "
                      "(float32 vs float64)")
        build = median_seconds(lambda: EmbreeScene(scene), repeats=3)
        for threads in (1, 2):
            subjects.append({"scene": name, "method": f"Embree (embreex), {threads} thread{'s' * (threads > 1)}",
                             "build": build, "calls": _queries(partial(embree.query, threads=threads),
                                                               partial(embree.query, threads=threads, kind="OCCLUDED"),
                                                               rays)})
    if "open3d" in competitors:
        open3d = Open3dScene(scene)
        subjects.append({"scene": name, "method": "Open3D RaycastingScene, 2 threads",
                         "build": median_seconds(lambda: Open3dScene(scene), repeats=3),
                         "calls": _queries(partial(open3d.query, threads=2),
                                           partial(open3d.query, threads=2, kind="OCCLUDED"), rays)})
    _interleaved_rates(subjects, console)

    brute = ra.build(scene, "none")
    subset = max(64, int(2e9 / len(scene) / 50))
    row = {"scene": name, "method": "rayaccel none (subset)", "build": brute.build_seconds}
    for label, (o, d) in rays.items():
        row[label] = subset / median_seconds(lambda: brute.intersect(o[:subset], d[:subset]), repeats=1) / 1e6
    row["any-hit"] = subset / median_seconds(lambda: brute.occluded(o[:subset], d[:subset]), repeats=1) / 1e6
    return subjects + [row]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=["bunny", "dragon"])
    parser.add_argument("--methods", nargs="+",
                        default=["grid", "hgrid", "grid-bvh", "kdtree", "octree", "bvh-binned", "bvh-lbvh"])
    parser.add_argument("--side", type=int, default=1024, help="primary rays are side x side; as many incoherent")
    args = parser.parse_args()
    console = Console(width=200)
    competitors = ensure_competitors()
    rows = []
    for name in args.scenes:
        with console.status(f"benchmarking {name}"):
            rows += bench_scene(name, args.methods, args.side, competitors, console)
    table = Table(title=f"closest hit, Mrays/s ({args.side}x{args.side} primary, as many incoherent); "
                        "ratios to Embree on 2 threads and to the best rayaccel BVH in this run")
    for column in ("scene", "method", "build s", "primary", "incoherent", "any-hit primary", "/Embree primary",
                   "/Embree incoherent", "/Embree any-hit", "/best BVH primary", "/best BVH incoherent"):
        table.add_column(column, justify="left" if column in ("scene", "method") else "right")
    for row in rows:
        same_scene = [r for r in rows if r["scene"] == row["scene"]]
        embree = next((r for r in same_scene if r["method"] == "Embree (embreex), 2 threads"), None)
        bvhs = [r for r in same_scene if r["method"].startswith("rayaccel bvh-") and "as given" not in r["method"]]
        to_embree = [f"{row[k] / embree[k]:.3f}" if embree else "-" for k in ("primary", "incoherent", "any-hit")]
        to_bvh = [f"{row[k] / max(r[k] for r in bvhs):.3f}" if bvhs else "-" for k in ("primary", "incoherent")]
        table.add_row(row["scene"], row["method"], f"{row['build']:.3f}", f"{row['primary']:.3g}",
                      f"{row['incoherent']:.3g}", f"{row['any-hit']:.3g}", *to_embree, *to_bvh)
    console.print(table)


if __name__ == "__main__":
    main()
