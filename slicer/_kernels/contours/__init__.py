"""Guaranteed contours: the quadtree of a layer plane, its bounds, root solves, refinement, chaining."""
