"""Bounding volume hierarchies: six builders, one flat layout, one traversal."""
