"""Numba's on-disk cache keyed by a kernel's source *and every source it may call into*.

Numba stamps each cached kernel with a hash of the one file that defines it
(``numba.core.caching``: ``get_source_stamp``, checked when the index file is
read). A kernel's compiled code also holds the code of the kernels it calls,
inlined or linked from other files, so an edit to a callee in another file
left the caller's stale code in the cache, running the old callee.

Here the stamp of a kernel defined in file ``f`` is a hash over ``f`` and
every module of its package that ``f`` imports, directly or through the
modules it imports in turn (the transitive closure of its ``import`` and
``from ... import`` statements that name modules of the same top-level
package). A jitted function can only reach globals of its own module, and
those are either defined there or imported from a module in that closure, so
every source a kernel's code comes from is hashed; an edit elsewhere in the
package (a module the kernel's file does not import) leaves its cache valid.
Numba's version is already part of its index; the stamp is a string, and the
cache stays where Numba puts it (``NUMBA_CACHE_DIR``, else ``__pycache__``
beside the source, else the user-wide cache folder when the package's folder
is read-only, as for a system-wide install), since only the stamp method of
Numba's locators is replaced.

Imports are found by a regular expression over the source lines rather than
by importing or parsing, so that stamping costs one read and one SHA-256 of
each of the package's files per process, at import time (where Numba's own
stamping hashed the defining file).
"""

from __future__ import annotations

import hashlib
import os
import re
from functools import cache

from numba.core import caching

__all__ = ["KernelCache", "dependency_stamp", "imported_modules"]

_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)"
                     r"|import[ \t]+([^\n#]+))", re.MULTILINE)


@cache
def _package_root(folder: str) -> str:
    """The folder of the top-level package holding ``folder`` (``folder`` itself when it is
    no package)."""
    root = folder
    while os.path.isfile(os.path.join(root, "__init__.py")):
        parent = os.path.dirname(root)
        if parent == root or not os.path.isfile(os.path.join(parent, "__init__.py")):
            break
        root = parent
    return root


@cache
def _modules(root: str) -> dict:
    """Every module under the package folder ``root``: dotted name (a tuple, the package's
    name first) -> file."""
    name = os.path.basename(root)
    found = {}
    for folder, folders, files in os.walk(root):
        folders[:] = [f for f in folders if f != "__pycache__"]
        package = (name, *os.path.relpath(folder, root).split(os.sep)) if folder != root else (name,)
        for file in files:
            if file == "__init__.py":
                found[package] = os.path.join(folder, file)
            elif file.endswith(".py"):
                found[(*package, file[:-3])] = os.path.join(folder, file)
    return found


@cache
def _source(path: str) -> tuple[str, str]:
    """``(text, sha256)`` of a source file, read once per process."""
    with open(path, "rb") as file:
        data = file.read()
    return data.decode("utf-8", errors="replace"), hashlib.sha256(data).hexdigest()


@cache
def imported_modules(path: str) -> frozenset:
    """The files of the modules of its own package that the source file ``path`` (absolute)
    imports, absolutely or relatively; ``from package import name`` counts the package's
    ``__init__.py`` and the submodule ``name`` when there is one."""
    root = _package_root(os.path.dirname(path))
    modules = _modules(root)
    folder = os.path.dirname(path)
    package = (os.path.basename(root), *os.path.relpath(folder, root).split(os.sep)) if folder != root \
        else (os.path.basename(root),)
    found = set()
    for statement in _IMPORT.finditer(_source(path)[0]):
        dots, name, names, plain = statement.groups()
        if plain is not None:
            for item in plain.split(","):
                dotted = tuple(item.split(" as ")[0].strip().split("."))
                found.update(modules[dotted[:k]] for k in range(1, len(dotted) + 1) if dotted[:k] in modules)
            continue
        parts = tuple(p for p in name.split(".") if p)
        if dots:
            up = len(dots) - 1
            parts = (package[:len(package) - up] if up < len(package) else ()) + parts
        if parts in modules:
            found.add(modules[parts])
        for item in names.strip("()").split(","):
            submodule = parts + (item.split(" as ")[0].strip(),)
            if submodule in modules:
                found.add(modules[submodule])
    found.discard(path)
    return frozenset(found)


@cache
def dependency_stamp(path: str) -> str:
    """A SHA-256 over the source file ``path`` and every module of its package it imports,
    directly or indirectly: the cache stamp of the kernels defined in ``path``."""
    start = os.path.realpath(path)
    skip = len(_package_root(os.path.dirname(start))) + 1
    seen = {start}
    todo = [start]
    while todo:
        for module in imported_modules(todo.pop()):
            if module not in seen:
                seen.add(module)
                todo.append(module)
    digest = hashlib.sha256()
    for module in sorted(seen):
        digest.update(f"{module[skip:]}\0{_source(module)[1]}\0".encode())
    return digest.hexdigest()


class _DependencyStamp:
    """Numba locator mixin: the stamp covers the file's imports too (see the module docstring)."""

    def get_source_stamp(self):
        return dependency_stamp(self._py_file)


class _UserProvidedLocator(_DependencyStamp, caching.UserProvidedCacheLocator):
    pass


class _InTreeLocator(_DependencyStamp, caching.InTreeCacheLocator):
    pass


class _UserWideLocator(_DependencyStamp, caching.UserWideCacheLocator):
    pass


class _CacheImpl(caching.CompileResultCacheImpl):
    _locator_classes = [_UserProvidedLocator, _InTreeLocator, _UserWideLocator, caching.ZipCacheLocator]


class KernelCache(caching.FunctionCache):
    """Numba's function cache with the dependency stamp; set as a dispatcher's ``_cache``
    in place of the ``FunctionCache`` that ``cache=True`` would give it."""

    _impl_class = _CacheImpl
