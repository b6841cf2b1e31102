"""Layers on their way out: orders of runs, placement on the plate and anti-aliasing."""
