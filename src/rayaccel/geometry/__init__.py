"""Intersection and overlap kernels: ray-triangle, ray-sphere, ray-box, triangle-box, sphere-box."""
