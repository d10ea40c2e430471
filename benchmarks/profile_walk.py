"""Where a ray walk spends its time, instruction by instruction.

Numba's compiled kernels carry no symbols a profiler can read, so ``perf`` alone
only says that the time went to anonymous memory. This script runs one query in
a loop under ``perf record`` (the ``cpu-clock`` software event, which works in
virtual machines without hardware counters), copies the machine code of the
process's anonymous executable regions to files before it exits, disassembles
them with ``objdump`` and lays the samples on the instructions: the hottest
instructions with the code around them, and the share of each 64-byte block.

    python benchmarks/profile_walk.py --scene forest-small-chair --rays incoherent --query closest
    python benchmarks/profile_walk.py --scene dragon --method grid-bvh --option density=0.01 --option mailbox=True

Needs ``perf`` and ``objdump`` (Debian: ``apt-get install -y linux-perf binutils``).
Results go to ``--out`` (default ``benchmarks/results/profile``): ``perf.data``,
the code regions, ``<region>.annotated.txt`` (every instruction with its share
of the samples) and ``summary.txt``. A sample lands on the instruction after the
one that stalled (the sampling's skid): read the hot spots with their context.
"""

from __future__ import annotations

import argparse
import ast
import collections
import ctypes
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

CONTEXT_LINES = 12
HOT_INSTRUCTIONS = 12
BLOCK_BYTES = 64


def _build_option(text: str) -> tuple[str, object]:
    """``(name, value)`` of a ``--option NAME=VALUE``: the value read as a Python literal, or kept
    as the text when it is none (``insert=exact``)."""
    name, separator, value = text.partition("=")
    if not separator or not name:
        raise argparse.ArgumentTypeError(f"takes NAME=VALUE, got {text!r}")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def trace(args) -> None:
    """The profiled child: run the query for ``args.seconds``, then copy the executable regions."""
    import numpy as np
    from _common import incoherent_rays, light_position, primary_rays, shadow_rays

    import rayaccel as ra
    from rayaccel._jit import set_threads

    set_threads(args.threads)
    scene = ra.load_scene(args.scene)
    accel = ra.build(scene, args.method, **dict(args.option))
    t_min, t_max = 0.0, np.inf
    if args.rays == "incoherent":
        origins, directions = incoherent_rays(scene, args.side * args.side)
    else:
        origins, directions = primary_rays(scene, args.side)
    if args.rays == "shadow":
        hits = accel.intersect(origins, directions)
        origins, directions = shadow_rays(origins, directions, hits.t, light_position(scene))
        t_min, t_max = 1e-4, 1.0
    query = accel.intersect if args.query == "closest" else accel.occluded
    query(origins, directions, t_min, t_max)
    start, calls = time.perf_counter(), 0
    while time.perf_counter() - start < args.seconds:
        query(origins, directions, t_min, t_max)
        calls += 1
    print(f"{calls} calls, {(time.perf_counter() - start) / calls * 1e3:.1f} ms each")
    with open("/proc/self/maps") as maps:
        for line in maps:
            fields = line.split()
            if "x" in fields[1] and len(fields) < 6:
                first, end = (int(part, 16) for part in fields[0].split("-"))
                (args.out / f"code_{first:x}.bin").write_bytes(ctypes.string_at(first, end - first))


def sampled_addresses(perf_data: Path) -> collections.Counter:
    """How many samples fell on each instruction address."""
    script = subprocess.run(["perf", "script", "-i", str(perf_data), "-F", "ip"], capture_output=True, text=True,
                            check=True)
    return collections.Counter(int(word, 16) for word in script.stdout.split())


def annotate(region: Path, first: int, samples: collections.Counter, total: int) -> list[tuple[float, int, str]]:
    """Disassemble ``region`` (loaded at ``first``) and write each instruction with its share of
    the ``total`` samples in the region; returns ``(share, address, line)`` for every instruction."""
    listing = subprocess.run(["objdump", "-D", "-b", "binary", "-mi386:x86-64", "-M", "intel",
                              f"--adjust-vma={first:#x}", str(region)], capture_output=True, text=True,
                             check=True).stdout
    rows = []
    for line in listing.splitlines():
        match = re.match(r"\s*([0-9a-f]+):", line)
        if match:
            address = int(match.group(1), 16)
            rows.append((samples.get(address, 0) / total, address, line.strip()))
    with open(region.with_suffix(".annotated.txt"), "w") as out:
        out.writelines(f"{100 * share:6.2f}  {line}\n" if share else f"        {line}\n" for share, _, line in rows)
    return rows


def summarize(args) -> str:
    """The hottest regions, their hottest instructions in context and their hottest 64-byte blocks."""
    samples = sampled_addresses(args.out / "perf.data")
    total = sum(samples.values())
    report = [f"{total} samples; {args.scene}, {args.method}, {args.rays} rays, {args.query} hit, "
              f"{args.threads} thread(s)"]
    for region in sorted(args.out.glob("code_*.bin")):
        first = int(region.stem.split("_")[1], 16)
        end = first + region.stat().st_size
        in_region = sum(count for address, count in samples.items() if first <= address < end)
        if in_region < 0.01 * total:
            continue
        rows = annotate(region, first, samples, in_region)
        report.append(f"\nregion {first:#x}: {100 * in_region / total:.1f} % of all samples (the process's "
                      f"start included); shares below are of this region's "
                      f"({region.with_suffix('.annotated.txt').name})")
        blocks = collections.Counter()
        for share, address, _ in rows:
            blocks[address // BLOCK_BYTES * BLOCK_BYTES] += share
        report.append("hottest 64-byte blocks: " + ", ".join(f"{address:#x} {100 * share:.1f} %"
                                                             for address, share in blocks.most_common(10)))
        for at in sorted(range(len(rows)), key=lambda k: rows[k][0], reverse=True)[:HOT_INSTRUCTIONS]:
            share, address, _ = rows[at]
            report.append(f"\n{100 * share:.2f} % at {address:#x}:")
            report.extend(f"  {100 * s:6.2f}  {line}" for s, _, line in rows[max(0, at - CONTEXT_LINES):at + 3])
    return "\n".join(report)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="forest-small-chair")
    parser.add_argument("--method", default="bvh-binned")
    parser.add_argument("--option", action="append", default=[], type=_build_option, metavar="NAME=VALUE",
                        help="a build option of the method, its value a Python literal (repeatable)")
    parser.add_argument("--rays", choices=("camera", "incoherent", "shadow"), default="incoherent")
    parser.add_argument("--query", choices=("closest", "any"), default="closest")
    parser.add_argument("--side", type=int, default=512, help="camera image side; incoherent rays: side squared")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=20.0, help="how long the query runs under perf")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "profile")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        trace(args)
        return
    missing = [tool for tool in ("perf", "objdump") if shutil.which(tool) is None]
    if missing:
        sys.exit(f"profile_walk.py needs {' and '.join(missing)}: apt-get install -y linux-perf binutils")
    args.out.mkdir(parents=True, exist_ok=True)
    for old in args.out.glob("code_*"):
        old.unlink()
    subprocess.run(["perf", "record", "-e", "cpu-clock", "-F", "2000", "-o", str(args.out / "perf.data"), "--",
                    sys.executable, __file__, "--child", *sys.argv[1:]], check=True)
    summary = summarize(args)
    (args.out / "summary.txt").write_text(summary + "\n")
    print(summary)


if __name__ == "__main__":
    main()
