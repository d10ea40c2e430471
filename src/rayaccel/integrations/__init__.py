"""Adapters that put rayaccel behind other libraries' interfaces.

Each adapter lives in its own module, named after the library it serves, and imports that
library only when the module itself is imported (``import rayaccel`` imports none of them):

- :mod:`rayaccel.integrations.trimesh`: ``mesh.ray`` and ``mesh.nearest`` of a ``trimesh.Trimesh``.
"""
