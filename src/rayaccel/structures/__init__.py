"""Acceleration structures behind one API: see :mod:`rayaccel.structures.registry`."""
