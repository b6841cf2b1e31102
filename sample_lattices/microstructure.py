"""Graded octet-truss microstructure: 2,976 struts, 25 mm across.

Mirrors the size of the microstructure benchmark of the seed paper (2,895
segments). A 6 x 6 x 5 grid of 5 mm octet cells is trimmed to a z-aligned
cylinder of radius 14.75 mm about the grid's axis, and the strut radius grows
linearly with z from 0.3 mm at the bottom to 0.6 mm at the top (struts are
tapered).
"""
from __future__ import annotations

from slicer.model.skeleton import Skeleton
from slicer.scene.lattice import generate_lattice

CELLS = (6, 6, 5)
CELL_SIZE = 5.0                 # mm
RADIUS_BOTTOM = 0.3             # mm
RADIUS_TOP = 0.6                # mm
ENVELOPE = ("cylinder", (15.0, 15.0), 14.75, 0.0, 25.0)


def build() -> Skeleton:
    """The graded microstructure.

    Returns
    -------
    Skeleton
        602 nodes and 2,976 struts; nodes within [2.5, 27.5] mm in x and y
        and [0, 25] mm in z; radii 0.3 mm (z = 0) to 0.6 mm (z = 25 mm).
    """
    return generate_lattice("octet", CELLS, CELL_SIZE, RADIUS_BOTTOM, radius_top=RADIUS_TOP,
                            grading_axis="z", envelope=ENVELOPE)
