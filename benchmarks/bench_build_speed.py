"""Warm build speed against a base copy of the package: did a change slow the builders down?

Compares the build time of ``--methods`` on ``--scene`` between this tree's
``rayaccel`` and a copy of another version imported under another name
(``--base``: a folder holding a package ``rayaccel_base``, e.g. made with
``cp -r /path/to/other/src/rayaccel /tmp/compile_base/rayaccel_base``; its
imports are relative, so it runs as it is). Both run in this one process, on one
Numba thread (``numba.set_num_threads(1)``; ``--threads`` for more), timed by ``time.process_time``, the CPU
time of the process, so that other work on this shared machine counts as little
as possible. Rounds interleave the two versions method by method after one
untimed warm-up build each (which also compiles or loads the kernels), and every
figure is the median over ``--rounds``. The trees are checked to be the same
size.

    python benchmarks/bench_build_speed.py --base /tmp/compile_base [--scene dragon]
                                           [--methods bvh-binned bvh-sah] [--rounds 5]
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys
import time
from pathlib import Path

import numba
from rich.console import Console
from rich.table import Table

import rayaccel as ra


def _build_seconds(package, scene, method) -> tuple[float, float, int]:
    """CPU and wall seconds of one build, and the size of what it built."""
    cpu, wall = time.process_time(), time.perf_counter()
    accel = package.build(scene, method)
    return time.process_time() - cpu, time.perf_counter() - wall, _size(accel)


def _size(accel) -> int:
    """A figure of the tree's size that both versions compute alike (nodes of a BVH)."""
    bvh = getattr(accel, "bvh", None)
    return len(bvh.node_first) if bvh is not None else -1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", type=Path, required=True, help="folder holding the package rayaccel_base")
    parser.add_argument("--scene", default="dragon")
    parser.add_argument("--methods", nargs="+", default=["bvh-binned"])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="Numba threads (CPU time then sums them)")
    args = parser.parse_args()
    sys.path.insert(0, str(args.base.resolve()))
    base = importlib.import_module("rayaccel_base")
    numba.set_num_threads(args.threads)
    console = Console(width=150)
    console.print(f"this tree: {Path(ra.__file__).parent}; base: {Path(base.__file__).parent}; "
                  f"{args.threads} Numba thread(s)")
    scenes = {"base": base.load_scene(args.scene), "this": ra.load_scene(args.scene)}
    packages = {"base": base, "this": ra}
    seconds = {(m, v): [] for m in args.methods for v in packages}
    sizes = {}
    for method in args.methods:
        for version, package in packages.items():
            sizes[method, version] = _build_seconds(package, scenes[version], method)[2]
    for _ in range(args.rounds):
        for method in args.methods:
            for version, package in packages.items():
                seconds[method, version].append(_build_seconds(package, scenes[version], method)[:2])
    table = Table(title=f"build seconds on {args.scene}, {args.threads} Numba thread(s), "
                        f"median of {args.rounds} interleaved rounds")
    for column in ("method", "CPU base", "CPU this", "this / base", "CPU base min-max", "CPU this min-max",
                   "wall base", "wall this", "nodes base / this"):
        table.add_column(column, justify="left" if column == "method" else "right")
    for method in args.methods:
        cpu = {v: [c for c, _ in seconds[method, v]] for v in packages}
        wall = {v: statistics.median(w for _, w in seconds[method, v]) for v in packages}
        b, t = (statistics.median(cpu[v]) for v in packages)
        spread = [f"{min(cpu[v]):.3f}-{max(cpu[v]):.3f}" for v in packages]
        table.add_row(method, f"{b:.3f}", f"{t:.3f}", f"{t / b:.3f}", *spread, f"{wall['base']:.3f}",
                      f"{wall['this']:.3f}", f"{sizes[method, 'base']} / {sizes[method, 'this']}")
    console.print(table)
    console.print(f"load average (1, 5, 15 min): {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
