"""Small lattices for quick tests and examples (built with generate_lattice)."""
from __future__ import annotations

from slicer.model.skeleton import Skeleton
from slicer.scene.lattice import generate_lattice


def cubic_2x2x2() -> Skeleton:
    """Simple cubic, 2 x 2 x 2 cells of 5 mm, radius 0.5 mm (27 nodes, 54 struts)."""
    return generate_lattice("cubic", (2, 2, 2), 5.0, 0.5)


def bcc_3x3x3_graded() -> Skeleton:
    """Body-centred cubic, 3 x 3 x 3 cells of 4 mm, radius 0.3 mm at z = 0 to 0.6 mm at z = 12 mm
    (91 nodes, 216 struts)."""
    return generate_lattice("bcc", (3, 3, 3), 4.0, 0.3, radius_top=0.6, grading_axis="z")


def octet_2x2x2() -> Skeleton:
    """Octet truss, 2 x 2 x 2 cells of 5 mm, radius 0.4 mm (63 nodes, 240 struts)."""
    return generate_lattice("octet", (2, 2, 2), 5.0, 0.4)


def kelvin_2x2x2() -> Skeleton:
    """Kelvin (truncated-octahedron) foam, 2 x 2 x 2 cells of 6 mm, radius 0.4 mm
    (144 nodes, 240 struts)."""
    return generate_lattice("kelvin", (2, 2, 2), 6.0, 0.4)
