"""The ``rayaccel`` command: demo, render, stats, build, experiments, report, calibration."""

from __future__ import annotations

import argparse
import ast
import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np

from .structures.registry import DEFAULT_METHOD

__all__ = ["main"]


class CliError(Exception):
    """A bad argument, reported as one line."""


def _parse_options(pairs) -> dict:
    options = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise CliError(f"option {pair!r} must look like key=value")
        key, text = pair.split("=", 1)
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            value = text
        options[key.strip().replace("-", "_")] = value
    return options


def _parse_vector(text: str, name: str) -> np.ndarray:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise CliError(f"{name} must be three comma-separated numbers, got {text!r}") from None
    if len(values) != 3 or not np.isfinite(values).all():
        raise CliError(f"{name} must be three finite comma-separated numbers, got {text!r}")
    return np.array(values)


def _load(spec: str, quiet: bool):
    from ._progress import status
    from .catalog import load_scene

    with status(f"loading {spec}", enabled=not quiet):
        return load_scene(spec)


def _build(scene, method: str, options: dict, quiet: bool):
    from ._progress import status
    from .structures.registry import build

    with status(f"building {method} over {len(scene):,} primitives", enabled=not quiet):
        try:
            return build(scene, method, **options)
        except TypeError as exc:
            raise CliError(f"bad option for {method}: {exc}") from None


def _is_saved(spec: str) -> bool:
    import zipfile

    return Path(spec).is_file() and zipfile.is_zipfile(spec)


def _accelerator(args):
    """The structure a render or stats command works on: a saved one read from ``args.scene``
    (``--method`` and ``-o`` do not apply then), or one built over the scene it names."""
    from ._progress import status

    if _is_saved(args.scene):
        from .persist import load_accelerator

        if args.option:
            raise CliError(f"{args.scene} is a saved accelerator: its options were fixed when it was built")
        with status(f"loading {args.scene}", enabled=not args.quiet):
            accel = load_accelerator(args.scene)
        if not args.quiet:
            print(f"loaded {accel.method} over {len(accel.scene):,} primitives in {accel.load_seconds:.3f} s")
        return accel
    return _build(_load(args.scene, args.quiet), args.method, _parse_options(args.option), args.quiet)


def _render(accel, args, quiet: bool, width: int, height: int, client=None):
    from ._progress import progress_bar
    from .rays import Camera
    from .render import default_camera, render

    camera = default_camera(accel)
    if getattr(args, "eye", None) or getattr(args, "target", None):
        eye = _parse_vector(args.eye, "--eye") if args.eye else camera.eye
        target = _parse_vector(args.target, "--target") if args.target else camera.target
        camera = Camera(eye, target, fov=args.fov)
    elif getattr(args, "fov", None) and args.fov != 40.0:
        camera = Camera(camera.eye, camera.target, fov=args.fov)
    lights = None
    if getattr(args, "light", None):
        lights = np.array([_parse_vector(text, "--light") for text in args.light])
    shadows = not getattr(args, "no_shadows", False)
    where = "" if client is None else f" on {len(client.nthreads())} Dask workers"
    with progress_bar(f"rendering {width}x{height} with {accel.method}{where}", height, enabled=not quiet) as advance:
        if client is None:
            return render(accel, camera, width, height, lights, shadows=shadows, progress=advance)
        from .distributed import render as render_tiles

        return render_tiles(accel, camera, width, height, lights, shadows=shadows, client=client, progress=advance)


@contextlib.contextmanager
def _cluster(args):
    """Yield the Dask client that ``--workers`` or ``--scheduler`` ask for, or None."""
    workers, scheduler = getattr(args, "workers", None), getattr(args, "scheduler", None)
    if workers is None and scheduler is None:
        yield None
        return
    if workers is not None and scheduler is not None:
        raise CliError("give --workers (a local Dask cluster) or --scheduler (an existing one), not both")
    if workers is not None and workers < 1:
        raise CliError(f"--workers must be at least 1, got {workers}")
    from ._progress import status
    from .distributed import connect

    with contextlib.ExitStack() as stack:
        with status(f"connecting to {scheduler or f'a local cluster of {workers} workers'}", enabled=not args.quiet):
            client = stack.enter_context(connect(workers=workers, scheduler=scheduler))
        yield client


def _write_images(result, out: Path, heatmap: str | None, title: str) -> list[Path]:
    from .render import save_heatmap, save_png

    written = [save_png(result.image, out)]
    if heatmap in ("nodes", "both"):
        written.append(save_heatmap(result.nodes, out.with_name(out.stem + "-nodes.png"), "nodes or cells visited",
                                    title))
    if heatmap in ("tests", "both"):
        written.append(save_heatmap(result.tests, out.with_name(out.stem + "-tests.png"), "primitive tests", title))
    return written


def _cmd_render(args) -> None:
    accel = _accelerator(args)
    width = args.width or args.size
    height = args.height or args.size
    with _cluster(args) as client:
        start = time.perf_counter()
        result = _render(accel, args, args.quiet, width, height, client)
        wall = time.perf_counter() - start
    out = Path(args.out or f"{Path(args.scene).stem.replace(':', '-')}-{accel.method}.png")
    for path in _write_images(result, out, args.heatmap, f"{args.scene}, {accel.method}"):
        print(f"wrote {path}")
    print(f"{accel.method}: build {accel.build_seconds:.3f} s, primary {result.mrays_per_second:.2f} Mrays/s, "
          f"shadow rays {result.shadow_rays:,} in {result.shadow_seconds:.3f} s"
          + ("" if client is None else f"; {wall:.3f} s wall clock on the cluster, structure sent included"))


def _stats_table(rows: list[dict], title: str):
    from rich.table import Table

    table = Table(title=title)
    table.add_column("statistic")
    for row in rows:
        table.add_column(str(row.get("label", row["method"])), justify="right")
    keys = [k for k in rows[0] if k not in ("method", "label")]
    for key in keys:
        if isinstance(rows[0].get(key), (list, dict)):
            continue
        cells = []
        for row in rows:
            value = row.get(key, "")
            if isinstance(value, float):
                cells.append(f"{value:,.4g}")
            else:
                cells.append(f"{value:,}" if isinstance(value, int) else str(value))
        table.add_row(key, *cells)
    return table


def _cmd_stats(args) -> None:
    from ._progress import table_console

    accel = _accelerator(args)
    table_console().print(_stats_table([accel.stats()], f"{args.scene} ({len(accel.scene):,} primitives)"))


def _cmd_build(args) -> None:
    scene = _load(args.scene, args.quiet)
    accel = _build(scene, args.method, _parse_options(args.option), args.quiet)
    out = Path(args.out)
    accel.save(out)
    print(f"{accel.method} over {len(scene):,} primitives: built in {accel.build_seconds:.3f} s, "
          f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")


def _cmd_demo(args) -> None:
    from rich.table import Table

    from ._progress import progress_bar, table_console
    from .precompile import compile_kernels
    from .structures.registry import methods

    console = table_console()
    scene = _load(args.scene, args.quiet)
    out_dir = Path(args.out)
    table = Table(title=f"rayaccel demo: {args.scene}, {len(scene):,} primitives, closest-hit primary rays")
    table.add_column("method", no_wrap=True, min_width=len(max(methods(), key=len)))
    for column in ("build s", "image", "Mrays/s", "cells or nodes/ray", "tests/ray", "shadow Mrays/s"):
        table.add_column(column, justify="right")
    with progress_bar("compiling kernels on every core (first run only, then cached)", len(methods()),
                      enabled=not args.quiet) as advance:
        compile_kernels(methods(), [scene.kind], progress=advance)
    written = []
    for method in methods():
        accel = _build(scene, method, {}, args.quiet)
        size = args.size
        if method == "none":
            # brute force costs n tests per ray: keep it to about 1e9 tests
            size = int(min(args.size, max(32, np.sqrt(1e9 / len(scene) / 2))))
        result = _render(accel, args, args.quiet, size, size)
        out = out_dir / f"{method}.png"
        files = _write_images(result, out, "both", f"{args.scene}, {method}")
        shadow_rate = result.shadow_rays / max(result.shadow_seconds, 1e-12) / 1e6
        table.add_row(method, f"{accel.build_seconds:.3f}", f"{size}x{size}", f"{result.mrays_per_second:.3g}",
                      f"{result.nodes.mean():.1f}", f"{result.tests.mean():.1f}", f"{shadow_rate:.3g}")
        written += files
    console.print(table)
    console.print("brute force renders a smaller image: it tests every primitive for every ray")
    console.print(f"images in {out_dir.resolve()}: " + ", ".join(p.name for p in written))


def _cmd_experiment(args) -> None:
    from functools import partial

    from ._progress import progress_bar
    from .experiments import runner

    if args.name != "grid-vs-none" and (args.workers is not None or args.scheduler is not None):
        raise CliError("--workers and --scheduler apply to experiment grid-vs-none only")
    if args.name != "kdtree-table" and args.method is not None:
        raise CliError("--method applies to experiment kdtree-table only")
    progress = partial(progress_bar, enabled=not args.quiet)
    with _cluster(args) as client:
        options = {"max_n": args.max_n, "client": client} if args.name == "grid-vs-none" else {}
        if args.name == "kdtree-table":
            options["method"] = args.method
        if args.name == "queries":
            options["points"] = args.points
        written = runner.run(args.name, args.out, args.size, args.scenes, progress, args.quick, **options)
    print(written.table.read_text())
    print(f"wrote {written.table} and {written.plot}"
          + (f", and {len(written.images)} more images" if written.images else ""))


def _cmd_report(args) -> None:
    from .report import write_report

    start = time.perf_counter()
    out = write_report(args.out, quick=args.quick, bench_results=args.bench_results, size=args.size,
                       show_progress=not args.quiet)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB) in {time.perf_counter() - start:.0f} s")


def _cmd_sdf(args) -> None:
    from ._progress import progress_bar
    from .sdf import sample_signed_distance, write_slices

    accel = _accelerator(args)
    if args.resolution < 2:
        raise CliError(f"--resolution must be at least 2, got {args.resolution}")
    start = time.perf_counter()
    with progress_bar(f"signed distance, {args.resolution} samples a side", args.resolution,
                      enabled=not args.quiet) as advance:
        sdf, lo, spacing = sample_signed_distance(accel, args.resolution, args.pad, progress=advance)
    seconds = time.perf_counter() - start
    out = Path(args.out)
    np.save(out, sdf)
    png = write_slices(sdf, lo, spacing, out.with_suffix(".png"), f"{args.scene}: signed distance")
    print(f"wrote {out} {sdf.shape} (origin {lo.tolist()}, spacing {spacing:.6g}) and {png}")
    print(f"{sdf.size:,} samples in {seconds:.2f} s ({sdf.size / seconds / 1e6:.2f} M/s), "
          f"{np.count_nonzero(sdf < 0):,} inside")


def _cmd_calibrate(args) -> None:
    from .scene import SPHERE, TRIANGLE
    from .structures.grid.calibrate import RATIO_VARIABLE, cache_path, calibration

    for name, kind in (("triangle", TRIANGLE), ("sphere", SPHERE)):
        entry = calibration(kind, refresh=True)
        print(f"{name}: C_i = {entry['intersection_seconds'] * 1e9:.2f} ns, "
              f"C_c = {entry['cell_step_seconds'] * 1e9:.2f} ns, "
              f"per-ray set-up {entry['ray_setup_seconds'] * 1e9:.1f} ns; C_i / C_c = {entry['ratio']:.2f} "
              f"+- {entry['uncertainty']:.1%} ({entry['source']}, {entry['attempts']} attempt(s))  ->  "
              f"cost-model grid has {2 * entry['ratio']:.1f} cells per primitive")
    print(f"cached in {cache_path()}")
    if os.environ.get(RATIO_VARIABLE):
        print(f"note: {RATIO_VARIABLE} is set, and grids use its ratio instead")


def _cmd_compile(args) -> None:
    import time

    from ._progress import progress_bar
    from .precompile import compile_kernels, default_workers
    from .scene import SPHERE, TRIANGLE
    from .structures.registry import methods

    chosen = args.methods or methods()
    unknown = sorted(set(chosen) - set(methods()))
    if unknown:
        raise CliError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(methods())}")
    kinds = [{"triangles": TRIANGLE, "spheres": SPHERE}[kind] for kind in args.kinds]
    workers = args.workers or default_workers()
    start = time.perf_counter()
    with progress_bar(f"compiling the kernels of {len(chosen)} method(s) on {workers} process(es)", len(chosen),
                      enabled=not args.quiet) as advance:
        compile_kernels(chosen, kinds, workers, progress=advance)
    print(f"kernels of {', '.join(chosen)} for {' and '.join(args.kinds)} compiled or found in the cache "
          f"in {time.perf_counter() - start:.1f} s")


def _cmd_methods(args) -> None:
    from .catalog import builtin_scenes
    from .structures.registry import build_class, methods

    for method in methods():
        summary = " ".join((build_class(method).__doc__ or "").strip().split("\n\n")[0].split())
        print(f"{method:18s} {summary}")
    print("scenes: " + ", ".join(builtin_scenes()) + ", or a mesh file (OBJ, PLY, STL, OFF, optionally .gz)")


def _parser() -> argparse.ArgumentParser:
    from .experiments.runner import names as runner_names

    parser = argparse.ArgumentParser(prog="rayaccel", description="Ray-tracing acceleration structures.")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    parser.add_argument("--threads", type=int, help="threads for parallel kernels (default: all cores)")
    sub = parser.add_subparsers(dest="command", required=True)

    def camera_args(p):
        p.add_argument("--eye", help="camera position x,y,z (default: automatic framing)")
        p.add_argument("--target", help="point looked at x,y,z")
        p.add_argument("--fov", type=float, default=40.0, help="vertical field of view in degrees")
        p.add_argument("--light", action="append", help="point light x,y,z (repeatable)")
        p.add_argument("--no-shadows", action="store_true", help="skip shadow rays")

    def cluster_args(p, what):
        p.add_argument("--workers", type=int, metavar="N",
                       help=f"{what} on a local Dask cluster of N worker processes (needs rayaccel[dask])")
        p.add_argument("--scheduler", metavar="ADDRESS",
                       help=f"{what} on the existing Dask cluster whose scheduler is at ADDRESS")

    demo = sub.add_parser("demo", help="render the default scene with every structure and compare them")
    demo.add_argument("--scene", default="bunny")
    demo.add_argument("--size", type=int, default=512)
    demo.add_argument("--out", default="rayaccel-demo")
    camera_args(demo)
    demo.set_defaults(func=_cmd_demo)

    render = sub.add_parser("render", help="render a scene to PNG, optionally with cost heatmaps")
    render.add_argument("scene", help="mesh file, built-in scene name, spheres:N, or a saved accelerator")
    render.add_argument("--method", default=DEFAULT_METHOD)
    render.add_argument("-o", "--option", action="append", help="structure option key=value (repeatable)")
    render.add_argument("--size", type=int, default=512)
    render.add_argument("--width", type=int)
    render.add_argument("--height", type=int)
    render.add_argument("--heatmap", choices=["nodes", "tests", "both"], help="also write cost heatmaps")
    render.add_argument("--out", help="output PNG (default: SCENE-METHOD.png)")
    camera_args(render)
    cluster_args(render, "render the image in tiles")
    render.set_defaults(func=_cmd_render)

    stats = sub.add_parser("stats", help="print the literature's statistics of a structure")
    stats.add_argument("scene", help="mesh file, built-in scene name, spheres:N, or a saved accelerator")
    stats.add_argument("--method", default=DEFAULT_METHOD)
    stats.add_argument("-o", "--option", action="append", help="structure option key=value (repeatable)")
    stats.set_defaults(func=_cmd_stats)

    build = sub.add_parser("build", help="build a structure and save it to one file (render and stats read it)")
    build.add_argument("scene", help="mesh file, built-in scene name, or spheres:N")
    build.add_argument("--method", default=DEFAULT_METHOD)
    build.add_argument("-o", "--option", action="append", help="structure option key=value (repeatable)")
    build.add_argument("--out", required=True, help="file to write (an uncompressed .npz, see rayaccel.persist)")
    build.set_defaults(func=_cmd_build)

    sdf = sub.add_parser("sdf", help="sample the signed distance on a grid; write .npy and a PNG of slices")
    sdf.add_argument("scene", help="mesh file, built-in scene name, spheres:N, or a saved accelerator")
    sdf.add_argument("--method", default=DEFAULT_METHOD)
    sdf.add_argument("-o", "--option", action="append", help="structure option key=value (repeatable)")
    sdf.add_argument("--resolution", type=int, default=128, help="samples along the box's longest side")
    sdf.add_argument("--pad", type=float, default=0.05, help="margin around the box, fraction of its size")
    sdf.add_argument("--out", default="sdf.npy", help=".npy file to write; the PNG goes beside it")
    sdf.set_defaults(func=_cmd_sdf)

    experiment = sub.add_parser("experiment", help="reproduce a lecture experiment")
    experiment.add_argument("name", choices=runner_names())
    experiment.add_argument("--quick", action="store_true",
                            help="small scenes, sizes and sweeps: a first look in seconds, not the lecture's figures")
    experiment.add_argument("--points", type=int, help="queries: query points (default 262,144)")
    experiment.add_argument("--max-n", type=int, help="grid-vs-none: largest scene size (default 1,000,000)")
    experiment.add_argument("--scenes", nargs="+", help="scenes to measure (structures: one scene)")
    experiment.add_argument("--method", help="kdtree-table: the structure tabulated (default kdtree)")
    experiment.add_argument("--size", type=int, help="image width and height (primary rays per side; default 512)")
    experiment.add_argument("--out", default="rayaccel-out", help="folder for the table and plot")
    cluster_args(experiment, "grid-vs-none: render the rows of 100,000 spheres or more in tiles")
    experiment.set_defaults(func=_cmd_experiment)

    report = sub.add_parser("report", help="run every lecture experiment and write one self-contained HTML page")
    report.add_argument("--quick", action="store_true", help="small scenes, sizes and sweeps: about a minute")
    report.add_argument("--out", type=Path, default=Path("report.html"),
                        help="the HTML page; the experiments' own files go to a folder beside it")
    report.add_argument("--size", type=int, help="image width and height of the experiments (default 512, quick 96)")
    report.add_argument("--bench-results", type=Path, metavar="DIR",
                        help="folder of benchmarks/bench_structures.py's results (default: benchmarks/results)")
    report.set_defaults(func=_cmd_report)

    calibrate = sub.add_parser("calibrate", help="measure C_i and C_c for the grid cost model")
    calibrate.set_defaults(func=_cmd_calibrate)

    compile_ = sub.add_parser("compile", help="compile the kernels of methods into the cache, on every core")
    compile_.add_argument("methods", nargs="*", metavar="METHOD", help="methods to compile (default: all)")
    compile_.add_argument("--kinds", nargs="+", choices=["triangles", "spheres"], default=["triangles", "spheres"],
                          help="primitive kinds to compile for (default: both)")
    compile_.add_argument("--workers", type=int, help="processes (default: one per core)")
    compile_.set_defaults(func=_cmd_compile)

    listing = sub.add_parser("methods", help="list methods and built-in scenes")
    listing.set_defaults(func=_cmd_methods)
    return parser


def main(argv=None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    for name in ("size", "width", "height"):
        value = getattr(args, name, None)
        if value is not None and not 1 <= value <= 16384:
            parser.error(f"--{name} must lie in 1 .. 16384, got {value}")
    from .scene import MeshLoadError

    try:
        if args.threads is not None:
            from ._jit import set_threads

            set_threads(args.threads)
        args.func(args)
    except (CliError, MeshLoadError, ValueError, TypeError, ImportError) as exc:
        print(f"rayaccel: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
