"""Numba's cache keyed by a kernel's file and the files it imports (``rayaccel._cache_key``):
an edited callee in another file recompiles its callers, an unrelated edit does not."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import rayaccel
from rayaccel import _cache_key

SRC = str(Path(rayaccel.__file__).resolve().parents[1])


def _write(folder: Path, files: dict) -> None:
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def _forget() -> None:
    """Drop what the stamping memoised in this process (it reads each file once per process)."""
    for memoised in (_cache_key.dependency_stamp, _cache_key.imported_modules, _cache_key._source,
                     _cache_key._modules, _cache_key._package_root):
        memoised.cache_clear()


@pytest.fixture()
def tree(tmp_path):
    _write(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/caller.py": "from .callee import value\nimport numpy as np\n",
        "pkg/callee.py": "from .deep.leaf import base  # noqa\n\ndef value():\n    return base()\n",
        "pkg/deep/__init__.py": "",
        "pkg/deep/leaf.py": "def base():\n    return 1\n",
        "pkg/other.py": "from . import callee, deep\nimport pkg.deep.leaf as leaf\n",
        "pkg/unrelated.py": "X = 1\n",
    })
    _forget()
    yield tmp_path / "pkg"
    _forget()


def test_imports_are_resolved_within_the_package(tree):
    def found(name):
        return sorted(Path(p).relative_to(tree).as_posix() for p in _cache_key.imported_modules(str(tree / name)))

    assert found("caller.py") == ["callee.py"]
    assert found("callee.py") == ["deep/leaf.py"]
    assert found("other.py") == ["__init__.py", "callee.py", "deep/__init__.py", "deep/leaf.py"]
    assert found("unrelated.py") == []


def test_stamp_follows_imports_transitively_and_ignores_unrelated_files(tree):
    before = _cache_key.dependency_stamp(str(tree / "caller.py"))
    (tree / "unrelated.py").write_text("X = 2\n")
    _forget()
    assert _cache_key.dependency_stamp(str(tree / "caller.py")) == before
    (tree / "deep" / "leaf.py").write_text("def base():\n    return 2\n")
    _forget()
    assert _cache_key.dependency_stamp(str(tree / "caller.py")) != before


_KERNELS = {
    "kpkg/__init__.py": "",
    "kpkg/callee.py": """
        from rayaccel._jit import inline_kernel

        @inline_kernel
        def value():
            return 1
        """,
    "kpkg/caller.py": """
        from rayaccel._jit import kernel
        from .callee import value

        @kernel
        def call():
            return value() + 10
        """,
}

_RUN = """
import json
import kpkg.caller as c
result = c.call()
print(json.dumps([result, sum(c.call.stats.cache_hits.values()), sum(c.call.stats.cache_misses.values()),
                  c.call._cache.cache_path]))
"""


def _run(folder: Path, env: dict) -> list:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(folder), SRC]), **env)
    out = subprocess.run([sys.executable, "-c", _RUN], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _edit_callee_and_check(folder: Path, env: dict) -> str:
    first = _run(folder, env)
    assert first[:3] == [11, 0, 1]  # compiled
    assert _run(folder, env)[:3] == [11, 1, 0]  # loaded from the cache
    (folder / "kpkg" / "callee.py").write_text((folder / "kpkg" / "callee.py").read_text().replace("1", "2"))
    assert _run(folder, env)[:3] == [12, 0, 1]  # the edited callee is compiled into the caller again
    return first[3]


def test_edited_callee_in_another_file_is_recompiled(tmp_path):
    _write(tmp_path, _KERNELS)
    cache = tmp_path / "numba-cache"
    where = _edit_callee_and_check(tmp_path, {"NUMBA_CACHE_DIR": str(cache)})
    assert Path(where).is_relative_to(cache)


def test_cache_falls_back_to_the_user_folder_when_the_package_folder_is_not_writable(tmp_path):
    """As for an installed package in a read-only folder: Numba's user-wide cache folder
    (under ``XDG_CACHE_HOME``) takes the kernels, with the same stamps. A file named
    ``__pycache__`` stands in for the read-only folder, as root may write anywhere."""
    _write(tmp_path, _KERNELS)
    (tmp_path / "kpkg" / "__pycache__").write_text("")
    env = {"NUMBA_CACHE_DIR": "", "XDG_CACHE_HOME": str(tmp_path / "user-cache"), "PYTHONDONTWRITEBYTECODE": "1"}
    where = _edit_callee_and_check(tmp_path, env)
    assert Path(where).is_relative_to(tmp_path / "user-cache")
