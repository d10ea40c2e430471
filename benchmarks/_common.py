"""Helpers shared by the benchmark scripts: competitor installation, timing, ray sets."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import numpy as np

from rayaccel._timing import median_seconds  # noqa: F401  (re-exported for the scripts)

ROOT = Path(__file__).resolve().parents[1]


def ensure_competitors() -> bool:
    """Import embreex, installing the ``bench`` extra first if it is missing."""
    try:
        importlib.import_module("embreex")
        return True
    except ImportError:
        print("installing the competitors: pip install -e '.[bench]'", flush=True)
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-e", f"{ROOT}[bench]"], check=False)
    try:
        importlib.invalidate_caches()
        importlib.import_module("embreex")
        return True
    except ImportError:
        print("embreex is not available here; competitor columns are left out", flush=True)
        return False


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
