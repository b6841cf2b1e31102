"""Launching compiled kernels: thread counts, resumable launches and borrowed array views."""
