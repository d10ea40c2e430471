"""Hybrids of the lecture: a uniform grid whose dense cells hold BVHs."""
