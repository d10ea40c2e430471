"""How stable is the grid cost model's calibration? Many calibrations in a row, idle and busy.

Runs the calibration of ``rayaccel.structures.grid.calibrate`` (with its retries
and fallback, exactly as a build with ``resolution="cost"`` does) ``--runs``
times per primitive kind, first on the machine as it is, then with one
busy-looping process per core started beside it, and prints per kind and
condition: how many calibrations fell back to the default ratio, how many
needed a retry, the ratio's median, min, max and max/min, and the median
reported uncertainty, beside the one-minute load average at the end of the
runs (busy-looping processes of our own included). The cache is not touched.

    python benchmarks/bench_calibration.py [--runs 20] [--conditions idle busy]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import warnings

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from rayaccel.scene import SPHERE, TRIANGLE
from rayaccel.structures.grid import calibrate as cal


def _spin() -> None:
    while True:
        pass


@contextlib.contextmanager
def _busy(enabled: bool):
    """One busy-looping process per core while the block runs (none when not ``enabled``)."""
    workers = [multiprocessing.Process(target=_spin, daemon=True) for _ in range(os.cpu_count() if enabled else 0)]
    for worker in workers:
        worker.start()
    try:
        yield
    finally:
        for worker in workers:
            worker.terminate()
            worker.join()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--conditions", nargs="+", default=["idle", "busy"], choices=["idle", "busy"])
    args = parser.parse_args()
    console = Console(width=150)
    for kind in (TRIANGLE, SPHERE):
        cal.calibrate(kind)
    table = Table(title=f"grid cost calibration, {args.runs} in a row per kind and condition")
    for column in ("kind", "condition", "load average", "fallbacks", "retried", "median C_i/C_c", "min", "max",
                   "max/min", "median uncertainty"):
        table.add_column(column, justify="left" if column in ("kind", "condition") else "right")
    with Progress(console=console) as progress:
        task = progress.add_task("calibrating", total=2 * len(args.conditions) * args.runs)
        for condition in args.conditions:
            with _busy(condition == "busy"):
                for kind, name in cal.KIND_NAMES.items():
                    entries = []
                    for _ in range(args.runs):
                        with warnings.catch_warnings():
                            warnings.simplefilter("ignore")
                            entries.append(cal._measure(kind))
                        progress.advance(task)
                    measured = np.array([e["ratio"] for e in entries if e["source"] == "measured"])
                    spread = [f"{measured.min():.3f}", f"{measured.max():.3f}",
                              f"{measured.max() / measured.min():.3f}"] if len(measured) else ["-"] * 3
                    fallbacks = sum(e["source"] == "default" for e in entries)
                    table.add_row(name, condition, f"{os.getloadavg()[0]:.1f}", str(fallbacks),
                                  str(sum(e["attempts"] > 1 for e in entries)),
                                  f"{np.median(measured):.3f}" if len(measured) else "-", *spread,
                                  f"{np.median([e['uncertainty'] for e in entries]):.1%}")
    console.print(table)


if __name__ == "__main__":
    main()
