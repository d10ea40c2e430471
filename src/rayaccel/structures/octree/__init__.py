"""Adaptive octree: build, layout, front-to-back traversal."""
