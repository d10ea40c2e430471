"""Where a single ray's time goes, against Embree: memory, branches or the work itself.

The same walk is timed on three kinds of batch of incoherent rays (one thread, closest hit and
any hit, nanoseconds a ray):

- distinct: every ray its own, as the throughput benchmark traces them;
- ``k`` rays repeated back to back: each of ``k`` rays traced many times in a row, so that its
  nodes and triangles are in the first-level cache and every branch of its walk is learned;
- ``k`` rays repeated in random order: the same rays and the same working set, but the
  branch predictor meets a different walk at each ray.

Where distinct rays cost more than rays repeated in random order, the difference is waiting for
memory; where rays in random order cost more than rays back to back, it is mispredicted
branches; what is left back to back is the walk's own work. A ratio to Embree that stays the
same in every regime says that the gap lies in that work. rayaccel's eight-wide BVH walks one
ray at a time here (``packets=False, interleave=False``): rays repeated back to back would
otherwise go in packets of identical rays, and a tree beyond the caches would keep several rays
in flight. Embree's figures include embreex's own cost per ray (its loop over the rays).

    python benchmarks/bench_regimes.py --scenes forest-small-chair dragon
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from _common import ROOT, ensure_competitors, incoherent_rays, median_seconds
from bench_structures import environment, markdown_table, rich_table
from peers import EmbreePeer, RaySet
from rich.console import Console

import rayaccel as ra
from rayaccel._jit import set_threads

REPEATED = (4096, 256, 32)
COLUMNS = ("scene", "rays", "query", "rayaccel ns/ray", "Embree ns/ray", "Embree / rayaccel")


def batches(origins, directions, seed: int = 1):
    """``(label, RaySet)`` of each regime, every batch as long as ``origins``."""
    n = len(origins)
    rng = np.random.default_rng(seed)
    yield "distinct", RaySet(origins, directions)
    for k in REPEATED:
        picks = np.repeat(np.arange(k), n // k)
        yield f"{k} rays, back to back", RaySet(origins[picks], directions[picks])
        picks = rng.permutation(picks)
        yield f"{k} rays, random order", RaySet(origins[picks], directions[picks])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["forest-small-chair", "dragon"])
    parser.add_argument("--rays", type=int, default=1 << 18)
    parser.add_argument("--repeat", type=int, default=5, help="timed calls per figure; the median is kept")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    console = Console()
    if "embreex" not in ensure_competitors(console):
        sys.exit("Embree (embreex) is needed for this comparison")
    set_threads(1)
    rows = []
    for name in args.scenes:
        scene = ra.load_scene(name)
        accel = ra.build(scene, "bvh-binned", packets=False, interleave=False)
        embree = EmbreePeer(scene)
        origins, directions = incoherent_rays(scene, args.rays)
        for label, rays in batches(origins, directions):
            prepared = embree.prepare(rays)
            queries = {"closest": (lambda: accel.intersect(rays.origins, rays.directions),
                                   lambda: embree.closest(prepared)),
                       "any hit": (lambda: accel.occluded(rays.origins, rays.directions),
                                   lambda: embree.any_hit(prepared))}
            for query, (ours, theirs) in queries.items():
                ours_ns = median_seconds(ours, args.repeat) / len(rays) * 1e9
                theirs_ns = median_seconds(theirs, args.repeat) / len(rays) * 1e9
                rows.append([name, label, query, f"{ours_ns:.0f}", f"{theirs_ns:.0f}", f"{theirs_ns / ours_ns:.2f}"])
    title = "One thread, nanoseconds a ray"
    console.print(rich_table(title, list(COLUMNS), rows))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "bench_regimes.md"
    machine = "".join(f"- {item}\n" for item in environment())
    path.write_text(machine + "\n" + markdown_table(title, list(COLUMNS), rows))
    console.print(f"wrote {path}")


if __name__ == "__main__":
    main()
