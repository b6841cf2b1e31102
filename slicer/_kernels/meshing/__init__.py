"""Compiled kernels of :mod:`slicer.meshing`: bounds of the field over balls of space."""
