"""Hierarchical grid: grids nested in the dense cells of grids, one flat layout, nested 3D-DDA."""
