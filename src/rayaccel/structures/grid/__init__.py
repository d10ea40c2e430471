"""Uniform grid with 3D-DDA traversal and mailboxing."""
