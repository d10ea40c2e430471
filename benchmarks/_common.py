"""Helpers shared by the benchmark scripts: competitor installation, timing, ray sets."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import numpy as np

from rayaccel._timing import median_seconds  # noqa: F401  (re-exported for the scripts)

ROOT = Path(__file__).resolve().parents[1]


COMPETITORS = {
    "embreex": "Embree 4 through embreex",
    "open3d": "Open3D RaycastingScene (Embree inside); needs Debian's libusb-1.0-0 to import",
}


def _importable(name: str) -> bool:
    try:
        importlib.import_module(name)
        return True
    except ImportError:
        return False


def ensure_competitors() -> set[str]:
    """The competitor modules that import, after installing the ``bench`` extra if any is missing."""
    if not all(_importable(name) for name in COMPETITORS):
        print("installing the competitors: pip install -e '.[bench]'", flush=True)
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-e", f"{ROOT}[bench]"], check=False)
        importlib.invalidate_caches()
    available = {name for name in COMPETITORS if _importable(name)}
    for name in sorted(set(COMPETITORS) - available):
        print(f"{COMPETITORS[name]} is not available here; its rows are left out", flush=True)
    return available


def primary_rays(scene, side: int):
    import rayaccel as ra

    b = scene.bounds()
    return ra.Camera.framing(b.scene_lo, b.scene_hi).rays(side, side)


def incoherent_rays(scene, n: int, seed: int = 0):
    """Origins uniform in the scene box, directions uniform on the sphere."""
    rng = np.random.default_rng(seed)
    b = scene.bounds()
    origins = rng.uniform(b.scene_lo, b.scene_hi, size=(n, 3))
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return origins, directions
