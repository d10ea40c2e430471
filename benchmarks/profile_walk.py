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

With ``--count`` the query runs ``--calls`` times under Valgrind's ``callgrind``
instead (``apt-get install -y valgrind``), which counts every instruction those
calls execute (collection is switched on for them alone), exactly and whatever
else runs on the host; the annotation then gives each instruction's count a ray.
Counted calls run about a hundred times slower than natively (16,384 of the
forest's incoherent rays: 0.9 s a call): keep ``--side`` small (128).

    python benchmarks/profile_walk.py --count --side 128 --option packets=False --option interleave=False

``--branches`` adds Valgrind's simulation of the branch predictor to the count
and lists the conditional branches it misses most: the way to find a choice
LLVM compiled to a branch where the code asked for a select (NUMBA_CPU_NAME
picks the instruction set compiled for, e.g. ``haswell`` for AVX2 code). The
simulated predictor is older than the host's: its misses point at candidates,
and only the time of a change says whether one costs. Under Valgrind the kernels
come out without AVX-512 instructions even on a host that has them (no ``zmm`` nor
mask register in the listing, 2026-12-06, Zen 4), so the counts are of AVX2-level
code: there the kd-tree step's float choices are branches, where the host's own
code makes them masked moves (see README, "Where the time goes").

    NUMBA_CPU_NAME=haswell python benchmarks/profile_walk.py --count --branches --side 128 --method kdtree

The scene is rounded to float32 as the benchmark gives it to every subject
(``_common.scene_every_subject_traces``). ``--peer embree`` counts Embree
(through embreex, one thread) on the same rays and triangles instead: its
library is a file with symbols, so its instructions are listed from that
file's code (``<library>.annotated.txt``) beside embreex's own.

    python benchmarks/profile_walk.py --count --side 128 --peer embree
"""

from __future__ import annotations

import argparse
import ast
import collections
import os
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
    """The profiled child: run the query for ``args.seconds`` (``args.calls`` times, counted, with
    ``--count``), then copy the executable regions."""
    import numpy as np
    from _common import incoherent_rays, light_position, primary_rays, scene_every_subject_traces, shadow_rays

    import rayaccel as ra
    from rayaccel._jit import set_threads

    set_threads(args.threads)
    scene = scene_every_subject_traces(args.scene)
    needs_accel = args.peer == "rayaccel" or args.rays == "shadow"
    accel = ra.build(scene, args.method, **dict(args.option)) if needs_accel else None
    t_min, t_max = 0.0, np.inf
    if args.rays == "incoherent":
        origins, directions = incoherent_rays(scene, args.side * args.side)
    else:
        origins, directions = primary_rays(scene, args.side)
    if args.rays == "shadow":
        hits = accel.intersect(origins, directions)
        origins, directions = shadow_rays(origins, directions, hits.t, light_position(scene))
        t_min, t_max = 1e-4, 1.0
    if args.peer == "rayaccel":
        query = accel.intersect if args.query == "closest" else accel.occluded
    else:
        from peers import EmbreePeer, RaySet

        embree = EmbreePeer(scene)
        prepared = embree.prepare(RaySet(origins, directions, t_min, t_max))
        answer = embree.closest if args.query == "closest" else embree.any_hit

        def query(*_):
            return answer(prepared)

    query(origins, directions, t_min, t_max)
    if args.count:
        subprocess.run(["callgrind_control", "--instr=on", str(os.getpid())], check=True, capture_output=True)
    start, calls = time.perf_counter(), 0
    while (calls < args.calls) if args.count else (time.perf_counter() - start < args.seconds):
        query(origins, directions, t_min, t_max)
        calls += 1
    if args.count:
        subprocess.run(["callgrind_control", "--instr=off", str(os.getpid())], check=True, capture_output=True)
    print(f"{calls} calls, {(time.perf_counter() - start) / calls * 1e3:.1f} ms each")
    if args.count:
        (args.out / "rays.txt").write_text(f"{calls * len(origins)}\n")
    with open("/proc/self/maps") as maps, open("/proc/self/mem", "rb", buffering=0) as memory:
        for line in maps:
            fields = line.split()
            if "x" in fields[1] and len(fields) < 6:
                first, end = (int(part, 16) for part in fields[0].split("-"))
                try:
                    code = os.pread(memory.fileno(), end - first, first)
                except OSError:
                    continue
                (args.out / f"code_{first:x}.bin").write_bytes(code)


def sampled_addresses(perf_data: Path) -> collections.Counter:
    """How many samples fell on each instruction address."""
    script = subprocess.run(["perf", "script", "-i", str(perf_data), "-F", "ip"], capture_output=True, text=True,
                            check=True)
    return collections.Counter(int(word, 16) for word in script.stdout.split())


def counted_addresses(callgrind_out: Path, event: str = "Ir") -> dict[str, collections.Counter]:
    """How many times each instruction address ran (``event`` ``Ir``), or with ``--branches`` was
    a conditional branch (``Bc``) or one the simulated predictor missed (``Bcm``), by the object
    file it belongs to (Numba's kernels under ``"???"``), from a ``callgrind`` profile written
    with ``--dump-instr=yes --dump-line=no --compress-pos=no --compress-strings=no``: the
    ``events:`` line names the columns, cost lines are ``address count ...`` (addresses in a
    shared library relative to its file, trailing zero counts left out), ``ob=`` names the
    object of the lines after it, and the line after each ``calls=`` line holds a call's
    inclusive cost, which is skipped."""
    counts = collections.defaultdict(collections.Counter)
    after_call, obj, column = False, "???", 1
    with open(callgrind_out) as lines:
        for line in lines:
            if line.startswith("events:"):
                column = 1 + line.split()[1:].index(event)
            elif line.startswith("ob="):
                obj = line[3:].strip()
            elif line.startswith("calls="):
                after_call = True
            elif line.startswith("0x"):
                fields = line.split()
                if not after_call and len(fields) > column:
                    counts[obj][int(fields[0], 16)] += int(fields[column])
                after_call = False
    return counts


def mispredicted_branches(conditional: collections.Counter, missed: collections.Counter,
                          rows: list[tuple[float, int, str]], first: int, end: int, rays: int) -> list[str]:
    """With ``--branches``: the conditional branches (``conditional``, by address) of the region
    from ``first`` to ``end`` a ray, those Valgrind's simulated predictor missed (``missed``; a
    simpler predictor than the host's, so a candidate to time, not a cost), and the branches it
    missed most, each in its context of ``rows``."""
    in_region = [address for address in missed if first <= address < end]
    report = [f"conditional branches {sum(conditional[a] for a in conditional if first <= a < end) / rays:.1f} a "
              f"ray, mispredicted in Valgrind's simulation {sum(missed[a] for a in in_region) / rays:.2f}"]
    at_row = {address: k for k, (_, address, _) in enumerate(rows)}
    for address in sorted(in_region, key=lambda a: -missed[a])[:HOT_INSTRUCTIONS // 2]:
        if missed[address] < 0.01 * rays:
            break
        report.append(f"\n{missed[address] / rays:.2f} mispredicted a ray of {conditional[address] / rays:.2f} at "
                      f"{address:#x}:")
        at = at_row.get(address, 0)
        report.extend(f"  {s:8.2f}  {line}" for s, _, line in rows[max(0, at - CONTEXT_LINES // 2):at + 2])
    return report


def annotate(region: Path, first: int, samples: collections.Counter, total: int, per_ray: bool = False,
             library: bool = False, out: Path | None = None) -> list[tuple[float, int, str]]:
    """Disassemble ``region`` (loaded at ``first``; with ``library``, a shared library's file, its
    code from the lowest to the highest address in ``samples``) and write each instruction with
    its share of ``total`` (the samples in the region, or with ``--count`` the rays traced) to
    ``out`` (by default ``region`` with the suffix ``.annotated.txt``); returns ``(share,
    address, line)`` for every instruction."""
    where = ([f"--start-address={min(samples):#x}", f"--stop-address={max(samples) + 16:#x}"] if library
             else ["-b", "binary", "-mi386:x86-64", f"--adjust-vma={first:#x}"])
    listing = subprocess.run(["objdump", "-d" if library else "-D", *where, "-M", "intel", str(region)],
                             capture_output=True, text=True, check=True).stdout
    rows = []
    for line in listing.splitlines():
        match = re.match(r"\s*([0-9a-f]+):", line)
        if match:
            address = int(match.group(1), 16)
            rows.append((samples.get(address, 0) / total, address, line.strip()))
    scale, width = (1, 8) if per_ray else (100, 6)
    with open(out or region.with_suffix(".annotated.txt"), "w") as listing_file:
        listing_file.writelines(f"{scale * share:{width}.2f}  {line}\n" if share else f"{'':{width}}  {line}\n"
                                for share, _, line in rows)
    return rows


def summarize(args) -> str:
    """The hottest regions, their hottest instructions in context and their hottest 64-byte blocks:
    as shares of the samples, or with ``--count`` as instructions a traced ray."""
    if args.count:
        by_object = counted_addresses(args.out / "callgrind.out")
        counts = by_object["???"]
        rays = int((args.out / "rays.txt").read_text())
        unit, scale = "instructions a ray", 1
        if args.branches:
            branches = [counted_addresses(args.out / "callgrind.out", event)["???"] for event in ("Bc", "Bcm")]
    else:
        counts = sampled_addresses(args.out / "perf.data")
        unit, scale = "%", 100
    total = sum(by_object[obj].total() for obj in by_object) if args.count else counts.total()
    subject = "Embree (embreex)" if args.peer == "embree" else args.method
    report = [f"{total} {'instructions' if args.count else 'samples'}; {args.scene}, {subject}, {args.rays} "
              f"rays, {args.query} hit, {args.threads} thread(s)"]
    if args.count:
        report.append("instructions a ray by object: " + ", ".join(
            f"{Path(obj).name} {by_object[obj].total() / rays:.1f}"
            for obj in sorted(by_object, key=lambda obj: -by_object[obj].total()) if by_object[obj].total() >= rays))
        for obj, obj_counts in by_object.items():
            if "embree" in Path(obj).name and obj_counts.total() >= rays:
                annotate(Path(obj), 0, obj_counts, rays, True, True, args.out / f"{Path(obj).name}.annotated.txt")
    for region in sorted(args.out.glob("code_*.bin")):
        first = int(region.stem.split("_")[1], 16)
        end = first + region.stat().st_size
        in_region = sum(count for address, count in counts.items() if first <= address < end)
        if in_region < (rays if args.count else 0.01 * total):
            continue
        rows = annotate(region, first, counts, rays if args.count else in_region, args.count)
        if args.count:
            report.append(f"\nregion {first:#x}: {in_region / rays:.1f} instructions a ray, "
                          f"{100 * in_region / total:.1f} % of the process's "
                          f"({region.with_suffix('.annotated.txt').name})")
        else:
            report.append(f"\nregion {first:#x}: {100 * in_region / total:.1f} % of all samples (the process's "
                          f"start included); shares below are of this region's "
                          f"({region.with_suffix('.annotated.txt').name})")
        blocks = collections.Counter()
        for share, address, _ in rows:
            blocks[address // BLOCK_BYTES * BLOCK_BYTES] += share
        report.append("hottest 64-byte blocks: " + ", ".join(f"{address:#x} {scale * share:.1f} {unit}"
                                                             for address, share in blocks.most_common(10)))
        if args.branches:
            report.extend(mispredicted_branches(*branches, rows, first, end, rays))
        for at in sorted(range(len(rows)), key=lambda k: rows[k][0], reverse=True)[:HOT_INSTRUCTIONS]:
            share, address, _ = rows[at]
            report.append(f"\n{scale * share:.2f} {unit} at {address:#x}:")
            report.extend(f"  {scale * s:8.2f}  {line}" for s, _, line in rows[max(0, at - CONTEXT_LINES):at + 3])
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
    parser.add_argument("--count", action="store_true",
                        help="count instructions under Valgrind's callgrind instead of sampling with perf")
    parser.add_argument("--peer", choices=("rayaccel", "embree"), default="rayaccel",
                        help="with --count: count Embree's query on the same rays instead of rayaccel's")
    parser.add_argument("--branches", action="store_true",
                        help="with --count: also simulate the branch predictor and list the branches it misses")
    parser.add_argument("--calls", type=int, default=1,
                        help="with --count: query calls counted (after a first one, not counted, that compiles)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "profile")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        trace(args)
        return
    if args.peer != "rayaccel" and not args.count:
        parser.error("--peer embree needs --count")
    if args.branches and not args.count:
        parser.error("--branches needs --count")
    profilers = ("valgrind", "callgrind_control") if args.count else ("perf",)
    missing = [tool for tool in (*profilers, "objdump") if shutil.which(tool) is None]
    if missing:
        sys.exit(f"profile_walk.py needs {' and '.join(missing)}: apt-get install -y "
                 f"{'valgrind' if args.count else 'linux-perf'} binutils")
    args.out.mkdir(parents=True, exist_ok=True)
    for old in args.out.glob("code_*"):
        old.unlink()
    child = [sys.executable, __file__, "--child", *sys.argv[1:]]
    if args.count:
        callgrind = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--dump-instr=yes", "--dump-line=no",
                     "--compress-pos=no", "--compress-strings=no", f"--callgrind-out-file={args.out / 'callgrind.out'}",
                     *(["--branch-sim=yes"] if args.branches else [])]
        subprocess.run([*callgrind, *child], check=True,
                       env={**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"})
    else:
        subprocess.run(["perf", "record", "-e", "cpu-clock", "-F", "2000", "-o", str(args.out / "perf.data"), "--",
                        *child], check=True)
    summary = summarize(args)
    (args.out / "summary.txt").write_text(summary + "\n")
    print(summary)


if __name__ == "__main__":
    main()
