"""Saving, loading and pickling built structures: one versioned, checksummed, validated format.

File format (``FORMAT_VERSION`` 1): an uncompressed ``.npz`` (a zip of ``.npy``
members, written by ``numpy.savez`` and read by ``numpy.load`` with
``allow_pickle=False``) holding

* ``__manifest__``: uint8, UTF-8 JSON: ``{"format": "rayaccel-accelerator",
  "version": 1, "rayaccel": <package version>, "state": ..., "arrays":
  {name: {"dtype", "shape"}}}``, where ``state`` nests the method, its
  options, the build time, the scene's kind and each structure's scalars (for
  a :class:`rayaccel.Scene`, one such state per object);
* the arrays, named ``scene.*`` (vertices and faces, or centres and radii),
  ``<structure>.*`` (the canonical arrays of :mod:`.layouts`), and for scenes
  ``instances.*``, ``top.*`` and ``object<k>.*`` for each object's state;

and, as the zip archive's comment (the file's last 23 bytes), the checksum
``rayaccel-crc32:XXXXXXXX``: the CRC-32 of every byte before it. A CRC-32
detects every corruption of up to 32 consecutive bits, so any flipped byte
anywhere in the file, zip headers included; a cryptographic hash would add
nothing against crafted files, which anyone can checksum again, so those are
stopped by the checks instead.

Loading checks, in order: the checksum, the manifest's format and version,
that the members are exactly the arrays listed with the listed dtype and
shape; then the scene is rebuilt through its validating constructors and
every structure array a kernel will read is checked (:mod:`.checks`) before
anything runs. A file failing any of these raises :class:`CorruptFileError`.

Pickling (``pickle.dumps(accel)``) goes through the same state and arrays,
and unpickling through the same checks.
"""

from __future__ import annotations

import io
import json
import mmap
import os
import re
import time
import zipfile
import zlib

import numpy as np

from .checks import CorruptFileError, require
from .state import describe, rebuild

__all__ = ["FORMAT", "FORMAT_VERSION", "CorruptFileError", "save", "load_accelerator", "reduce_accelerator"]

FORMAT = "rayaccel-accelerator"
FORMAT_VERSION = 1
_MANIFEST = "__manifest__"
_TRAILER = re.compile(rb"rayaccel-crc32:([0-9a-f]{8})")
_TRAILER_LENGTH = 23
_END_OF_ZIP = 22  # an end-of-central-directory record without comment


def _manifest(state: dict, arrays: dict) -> bytes:
    from .. import __version__

    listing = {name: {"dtype": a.dtype.str, "shape": list(a.shape)} for name, a in arrays.items()}
    return json.dumps({"format": FORMAT, "version": FORMAT_VERSION, "rayaccel": __version__, "state": state,
                       "arrays": listing}, sort_keys=True).encode()


def save(accel, path) -> None:
    """Write ``accel`` to ``path`` in the format above (the name is used as given)."""
    state, arrays = describe(accel)
    write_members(path, {_MANIFEST: np.frombuffer(_manifest(state, arrays), np.uint8), **arrays})


def write_members(path, members: dict) -> None:
    """Write the named arrays as an uncompressed ``.npz`` followed by the checksum trailer."""
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    data = buffer.getbuffer()
    end = data[len(data) - _END_OF_ZIP:]
    if bytes(end[:4]) != b"PK\x05\x06" or bytes(end[-2:]) != b"\x00\x00":  # pragma: no cover - numpy's zip
        raise RuntimeError("unexpected end of the zip archive numpy wrote")
    end[-2:] = _TRAILER_LENGTH.to_bytes(2, "little")
    trailer = b"rayaccel-crc32:%08x" % zlib.crc32(data)
    with open(os.fspath(path), "wb") as f:
        f.write(data)
        f.write(trailer)


def _verify_checksum(path: str) -> None:
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        require(size > _TRAILER_LENGTH + _END_OF_ZIP, f"{path} is too short to be a saved accelerator")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
            match = _TRAILER.fullmatch(mapped[size - _TRAILER_LENGTH:])
            require(match is not None, f"{path} has no rayaccel checksum: not a saved accelerator, or truncated")
            with memoryview(mapped) as view:
                crc = zlib.crc32(view[:size - _TRAILER_LENGTH])
    require(crc == int(match.group(1), 16), f"checksum mismatch: {path} is corrupted")


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
    _verify_checksum(path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            require(_MANIFEST in npz.files, "the manifest is missing")
            manifest = npz[_MANIFEST]
            require(manifest.dtype == np.uint8 and manifest.ndim == 1, "the manifest is not a byte string")
            header = _parse(manifest.tobytes())
            listing = header["arrays"]
            require(set(npz.files) == set(listing) | {_MANIFEST},
                    "the file's members differ from those its manifest lists")
            arrays = {}
            for name, entry in listing.items():
                a = npz[name]
                require(a.dtype.str == entry.get("dtype") and list(a.shape) == entry.get("shape"),
                        f"{name} has dtype {a.dtype.str} and shape {list(a.shape)}, the manifest says otherwise")
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
