"""All hits and hit counts against Open3D's ``RaycastingScene.list_intersections`` / ``count_intersections``.

The full dragon (871,414 triangles), 1024 x 1024 primary camera rays and as many incoherent rays (origins
uniform in the dragon's box, directions uniform on the sphere), as in ``bench_structures.py``. Every
subject answers each query once as a warm-up (its answers compared with rayaccel's), then ``ROUNDS``
interleaved rounds are timed; the figures are medians, in million rays per second, with rayaccel's
ratio to Open3D. Builds are not timed here (``bench_structures.py`` times them).

Semantics, read from Open3D's ``RaycastingScene.cpp`` (0.19/0.20): rays are float32, searched over
``[0, inf)`` (a hit at t = 0 counts, as in rayaccel's closed interval starting at 0); both queries
collect hits through an Embree intersection filter that rejects every hit so the ray goes on, and
skip a hit of the same geometry whose primitive *or* distance equals the last one recorded for
that ray. So a shared edge crossed by two triangles at bit-identical float32 distances, reported
one after the other, counts once, but not reliably otherwise (the two distances are computed by
two triangles, and Embree's watertight test reports both); and duplicated triangles (two primitives
at the same distance) count once. rayaccel reports every primitive crossed once, gives each crossing
of a shared edge or vertex to exactly one triangle, and keeps duplicates (both). ``list_intersections``
does a counting pass first, then a listing pass (rayaccel's ``intersect_all`` lists in one walk the rays
whose hits fit its first slots, see ``Accelerator._nearest_hits``); its hits are
grouped per ray in the order Embree met them (not sorted by distance), rayaccel's are sorted by
``(t, prim)``. The "agree" column is the share of rays whose counts are equal.

Run: ``python benchmarks/bench_ray_queries.py [--side 1024] [--rounds 5] [--method bvh-binned]``.
"""

from __future__ import annotations

import argparse
import os
import platform

import numpy as np
from _common import ensure_competitors, incoherent_rays, primary_rays, settled_seconds

import rayaccel as ra
from rayaccel.experiments.queries import open3d_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="dragon")
    parser.add_argument("--side", type=int, default=1024)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--method", default="bvh-binned")
    args = parser.parse_args()
    have_open3d = "open3d" in ensure_competitors()
    mesh = ra.load_scene(args.scene)
    accel = ra.build(mesh, args.method)
    rays = {"primary": primary_rays(mesh, args.side), "incoherent": incoherent_rays(mesh, args.side ** 2)}
    calls = []
    for name, (o, d) in rays.items():
        calls.append(("rayaccel", name, "count", lambda o=o, d=d: accel.count(o, d)))
        calls.append(("rayaccel", name, "list", lambda o=o, d=d: np.diff(accel.intersect_all(o, d).offsets)))
    if have_open3d:
        scene, open3d = open3d_scene(mesh)
        cores = os.cpu_count() or 1
        for name, (o, d) in rays.items():
            tensor = open3d.core.Tensor(np.hstack([o, d]).astype(np.float32))
            calls.append(("Open3D", name, "count",
                          lambda t=tensor: scene.count_intersections(t, nthreads=cores).numpy().astype(np.int64)))
            calls.append(("Open3D", name, "list",
                          lambda t=tensor: np.diff(scene.list_intersections(t, nthreads=cores)["ray_splits"]
                                                   .numpy().astype(np.int64))))
    seconds = {call[:3]: [] for call in calls}
    answers = {}
    for round_ in range(args.rounds + 1):
        for who, name, query, run in calls:
            if round_:
                seconds[who, name, query].append(settled_seconds(run))
            else:
                answers[who, name, query] = run()
    n = args.side ** 2
    print(f"{args.scene}, {len(mesh.faces):,} triangles, {n:,} rays per set, rayaccel {args.method}, "
          f"median of {args.rounds} interleaved rounds; {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"{'rays':11s} {'query':6s} {'rayaccel':>9s} {'Open3D':>9s} {'ratio':>6s} {'agree':>7s} {'hits/ray':>8s}")
    for name in rays:
        for query in ("count", "list"):
            ours = n / float(np.median(seconds["rayaccel", name, query])) / 1e6
            line = f"{name:11s} {query:6s} {ours:9.2f}"
            if have_open3d:
                theirs = n / float(np.median(seconds["Open3D", name, query])) / 1e6
                agree = float(np.mean(answers["rayaccel", name, query] == answers["Open3D", name, query]))
                line += f" {theirs:9.2f} {ours / theirs:6.2f} {agree:7.4f}"
            print(line + f" {answers['rayaccel', name, query].mean():8.2f}")


if __name__ == "__main__":
    main()
