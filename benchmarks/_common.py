"""Helpers shared by the benchmark scripts: competitor installation, timing, ray sets."""

from __future__ import annotations

import importlib
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import rayaccel as ra
from rayaccel._timing import median_seconds  # noqa: F401  (re-exported for the scripts)

ROOT = Path(__file__).resolve().parents[1]

COMPETITORS = {
    "embreex": "Embree 4 through embreex",
    "open3d": "Open3D RaycastingScene (Embree inside)",
    "mitsuba": "Mitsuba 3, variant llvm_ad_rgb (Embree inside, driven by Dr.Jit)",
}

LIBUSB_HINT = "apt-get install -y libusb-1.0-0"
LLVM_HINT = "apt-get install -y llvm"
SETTLE_SECONDS = 0.05
"""Idle time before each timed query of a benchmark that interleaves subjects (:func:`settled_seconds`)."""


def settled_seconds(run) -> float:
    """The seconds ``run()`` takes as a subject meets its query in a loop of its own: after a
    pause of :data:`SETTLE_SECONDS` and one untimed call. The pause: Dr.Jit's thread pool (Mitsuba)
    keeps its workers busy for some milliseconds after a call, and whichever subject ran next paid
    for it (forest scene: rayaccel's camera-ray any hit took 21.0 ms right after a Mitsuba call
    against 13.1 ms alone; after a pause of 20 ms 14.1); Open3D's thread pool was not measured. The untimed
    call: a query after an idle pause runs cold (the same query alone, back to back 9.3 ms, after
    a pause of 10 ms 9.8, 30 ms 12.5, 50 ms 13.2), so each subject is timed on its second call,
    its structure and rays in the caches as a renderer's loop finds them."""
    time.sleep(SETTLE_SECONDS)
    run()
    start = time.perf_counter()
    run()
    return time.perf_counter() - start


def scene_every_subject_traces(name: str):
    """The scene ``name`` with its vertices rounded to float32, as every peer stores them, so that
    rayaccel traces the same triangles as the peers it is compared with. The scanned meshes are
    float32 already; the procedural forest is built in float64, and given as it is, rayaccel would
    trace triangles a few float32 ulps away from the peers' (and keep them in its indexed layout
    instead of float32 lanes, :mod:`rayaccel.geometry.gather`)."""
    scene = ra.load_scene(name)
    if isinstance(scene, ra.TriangleMesh) and not scene.float32_exact:
        scene = ra.TriangleMesh(scene.vertices.astype(np.float32), scene.faces)
    return scene


def _check_mitsuba() -> None:
    """Mitsuba imports without its JIT; the variant the benchmark uses needs libLLVM at run time."""
    import mitsuba

    mitsuba.set_variant("llvm_ad_rgb")


def import_problem(name: str) -> tuple[str, str | None] | None:
    """None if competitor ``name`` imports and works here, else ``(reason, command that fixes it or None)``."""
    try:
        importlib.import_module(name)
        if name == "mitsuba":
            _check_mitsuba()
    except ModuleNotFoundError as error:
        return f"not installed ({error})", f"pip install -e '{ROOT}[bench]'"
    except OSError as error:
        if "libusb" in str(error):
            return f"Debian's libusb-1.0-0 is missing ({error})", LIBUSB_HINT
        return f"a shared library failed to load ({error})", None
    except Exception as error:  # noqa: BLE001 - any failure is reported, never hidden
        fix = LLVM_HINT if name == "mitsuba" else None  # Dr.Jit's LLVM backend loads libLLVM at run time
        return f"{type(error).__name__}: {error}", fix
    return None


def ensure_competitors(console=None) -> set[str]:
    """The competitors that work here, after installing the ``bench`` extra if one is not
    installed. Each one that does not work is printed in bold red with the reason and, where
    known, the command that fixes it."""
    def say(text: str, style: str | None = None) -> None:
        if console is None:
            print(text, flush=True)
        else:
            console.print(text, style=style, markup=False, highlight=False)

    problems = {name: import_problem(name) for name in COMPETITORS}
    if any(p and p[0].startswith("not installed") for p in problems.values()):
        say(f"installing the competitors: pip install -e '{ROOT}[bench]'")
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-e", f"{ROOT}[bench]"], check=False)
        importlib.invalidate_caches()
        problems = {name: import_problem(name) for name in COMPETITORS}
    for name, problem in problems.items():
        if problem:
            reason, fix = problem
            message = f"COMPETITOR MISSING: {COMPETITORS[name]} cannot run here; its rows are left out. {reason}"
            say(message, style="bold red")
            if fix:
                say(f"    to fix it, run:  {fix}")
    return {name for name, problem in problems.items() if problem is None}


def primary_rays(scene, side: int):
    """Pinhole-camera rays through the pixel centres of a ``side`` x ``side`` image framing the scene."""
    return scene_camera(scene).rays(side, side)


def scene_camera(scene):
    """The camera that frames the scene's box from the front, slightly above and to the right."""
    b = scene.bounds()
    return ra.Camera.framing(b.scene_lo, b.scene_hi)


def incoherent_rays(scene, n: int, seed: int = 0):
    """Origins uniform in the scene box, directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    origins = rng.uniform(b.scene_lo, b.scene_hi, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins, directions


def light_position(scene) -> np.ndarray:
    """A point light above and in front of the scene: the framing camera's eye raised along +y
    by the radius of the scene's bounding sphere."""
    b = scene.bounds()
    radius = 0.5 * float(np.linalg.norm(b.scene_hi - b.scene_lo))
    return scene_camera(scene).eye + np.array([0.0, radius, 0.0])


def shadow_rays(origins, directions, t_hit, light):
    """Rays from the finite hits ``origins + t_hit * directions`` toward ``light``: origins at the
    hit points and directions ``light - origin`` (not normalised, so that the light is at t = 1)."""
    hit = np.isfinite(t_hit)
    points = origins[hit] + t_hit[hit, None] * directions[hit]
    return points, np.asarray(light, float)[None, :] - points
