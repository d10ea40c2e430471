"""Saving, loading and pickling built structures: one versioned, checksummed, validated format.

File format (``FORMAT_VERSION`` 1): an uncompressed ``.npz`` (a zip of ``.npy``
members, written by ``numpy.savez`` and read by ``numpy.load`` with
``allow_pickle=False``) holding

* ``__manifest__``: uint8, UTF-8 JSON: ``{"format": "rayaccel-accelerator",
  "version": 1, "rayaccel": <package version>, "state": ..., "arrays":
  {name: {"dtype", "shape", "crc32"}}}``, where ``state`` nests the method,
  its options, the build time, the scene's kind and each structure's scalars
  (for a :class:`rayaccel.Scene`, one such state per object);
* ``__checksum__``: uint8, the SHA-256 hex digest of the manifest's bytes.
  The manifest lists every array's CRC-32, so the digest covers all of them;
* the arrays, named ``scene.*`` (vertices and faces, or centres and radii),
  ``<structure>.*`` (the canonical arrays of :mod:`.layouts`), and for scenes
  ``instances.*``, ``top.*`` and ``object<k>.*`` for each object's state.

Loading checks, in order: the zip is readable, the digest matches the
manifest, the format and version are known, the members are exactly the
arrays listed, each has the listed dtype, shape and CRC-32; then the scene
is rebuilt through its validating constructors and every structure array a
kernel will read is checked (:mod:`.checks`) before anything runs. A file
failing any of these raises :class:`CorruptFileError`.

Pickling (``pickle.dumps(accel)``) goes through the same state and arrays,
and unpickling through the same checks.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import zipfile
import zlib

import numpy as np

from .checks import CorruptFileError, require
from .state import rebuild, describe

__all__ = ["FORMAT", "FORMAT_VERSION", "CorruptFileError", "save", "load_accelerator", "reduce_accelerator"]

FORMAT = "rayaccel-accelerator"
FORMAT_VERSION = 1
_MANIFEST = "__manifest__"
_CHECKSUM = "__checksum__"


def _crc32(a: np.ndarray) -> int:
    return zlib.crc32(memoryview(np.ascontiguousarray(a)).cast("B"))


def _manifest(state: dict, arrays: dict) -> bytes:
    from .. import __version__

    listing = {name: {"dtype": a.dtype.str, "shape": list(a.shape), "crc32": _crc32(a)} for name, a in arrays.items()}
    return json.dumps({"format": FORMAT, "version": FORMAT_VERSION, "rayaccel": __version__, "state": state,
                       "arrays": listing}, sort_keys=True).encode()


def save(accel, path) -> None:
    """Write ``accel`` to ``path`` in the format above (the name is used as given)."""
    state, arrays = describe(accel)
    manifest = _manifest(state, arrays)
    digest = hashlib.sha256(manifest).hexdigest().encode()
    members = {_MANIFEST: np.frombuffer(manifest, np.uint8), _CHECKSUM: np.frombuffer(digest, np.uint8), **arrays}
    with open(os.fspath(path), "wb") as f:
        np.savez(f, **members)


def _read_member(npz, name):
    try:
        return npz[name]
    except KeyError:
        raise CorruptFileError(f"member {name!r} is missing") from None


def load_accelerator(path):
    """Read a structure written by ``accel.save(path)``: the same results as the saved one,
    bit for bit, without rebuilding.

    Raises
    ------
    CorruptFileError
        The file is truncated, corrupted, of another format or version, or holds arrays of
        the wrong shape, dtype or range; nothing of it reaches a kernel then.
    FileNotFoundError
        No such file.
    """
    start = time.perf_counter()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"no saved accelerator at {path}")
    try:
        with np.load(path, allow_pickle=False) as npz:
            manifest = _read_member(npz, _MANIFEST)
            checksum = _read_member(npz, _CHECKSUM)
            require(manifest.dtype == np.uint8 and manifest.ndim == 1, "the manifest is not a byte string")
            require(hashlib.sha256(manifest.tobytes()).hexdigest().encode() == checksum.tobytes(),
                    "checksum mismatch: the manifest is corrupted")
            header = _parse(manifest.tobytes())
            listing = header["arrays"]
            require(set(npz.files) == set(listing) | {_MANIFEST, _CHECKSUM},
                    "the file's members differ from those its manifest lists")
            arrays = {}
            for name, entry in listing.items():
                a = npz[name]
                require(a.dtype.str == entry.get("dtype") and list(a.shape) == entry.get("shape"),
                        f"{name} has dtype {a.dtype.str} and shape {list(a.shape)}, the manifest says otherwise")
                require(_crc32(a) == entry.get("crc32"), f"checksum mismatch in {name}: the file is corrupted")
                arrays[name] = a
    except CorruptFileError:
        raise
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError, zlib.error) as exc:
        raise CorruptFileError(f"{path} is not a readable rayaccel accelerator file: {exc}") from None
    accel = rebuild(header["state"], arrays)
    accel.load_seconds = time.perf_counter() - start
    return accel


def _parse(manifest: bytes) -> dict:
    try:
        header = json.loads(manifest.decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CorruptFileError(f"the manifest is not JSON: {exc}") from None
    require(isinstance(header, dict) and header.get("format") == FORMAT, "not a rayaccel accelerator file")
    version = header.get("version")
    require(version == FORMAT_VERSION,
            f"format version {version!r} is not supported (this rayaccel reads version {FORMAT_VERSION})")
    require(isinstance(header.get("arrays"), dict) and isinstance(header.get("state"), dict),
            "the manifest lacks its arrays or state")
    require(all(isinstance(entry, dict) for entry in header["arrays"].values()), "the manifest's arrays are malformed")
    return header


def _unpickle(state_json: bytes, arrays: dict):
    state = json.loads(state_json.decode())
    require(isinstance(state, dict), "a pickled accelerator's state is malformed")
    return rebuild(state, dict(arrays))


def reduce_accelerator(accel):
    """``__reduce__`` of every accelerator: the state and arrays of the file format."""
    state, arrays = describe(accel)
    return _unpickle, (json.dumps(state).encode(), arrays)
