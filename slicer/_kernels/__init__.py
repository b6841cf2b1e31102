"""Compiled kernels: the only package that imports Numba.

Kernels take plain contiguous arrays, never raise on data, and return status
codes; the public modules in :mod:`slicer` validate inputs and call them.
"""
