"""Layer areas (peel forces) and the print time and resin estimate.

The cured area of a layer (solid pixels x pixel area) is what the layer
sticks to the vat's film with, so the force of each peel grows with it; a
sudden jump from one layer to the next is where prints tear. The resin
volume is the grey-weighted voxel volume (grey 255 = one full voxel), as
the SL1 and GOO writers record it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from formats.printers import PrintSettings

from ..grid import SliceGrid
from .stream import rounded

#: layer-to-layer jumps listed in a report
TOP_JUMPS = 5
#: time per layer besides exposure (lift, tilt) without a printer profile, s
#: (the default of :class:`formats.printers.Printer`)
DEFAULT_LAYER_OVERHEAD = 8.0


@dataclass
class AreaStats:
    """Per-layer cured area and grey sum, accumulated one layer at a time.

    Parameters
    ----------
    grid : SliceGrid
    """

    grid: SliceGrid
    area: list = field(default_factory=list)         # mm² per layer
    grey: list = field(default_factory=list)         # sum of grey / 255 per layer (voxels)

    def add(self, k: int, solid: np.ndarray, image: np.ndarray) -> None:
        px, py = self.grid.pixel_size
        self.area.append(float(np.count_nonzero(solid)) * px * py)
        self.grey.append(float(image.sum(dtype=np.uint64)) / 255.0)

    def summary(self, max_jump: float | None = None) -> dict:
        """``per_layer`` (mm²), ``largest`` (``layer``, ``area``), ``jumps``
        (the largest increases, ``layer``, ``from``, ``to``, ``jump``, mm²),
        ``max_jump`` and, with ``max_jump``, ``over`` (the jumps above it)."""
        a = np.asarray(self.area, dtype=np.float64)
        out: dict = {"per_layer": [rounded(v) for v in a.tolist()], "largest": None, "jumps": [],
                     "max_jump": 0.0}
        if a.size == 0:
            return out
        k = int(np.argmax(a))
        out["largest"] = {"layer": k, "area": rounded(a[k])}
        d = np.diff(a, prepend=0.0)
        d[0] = 0.0                                     # the first layer's area is not a jump
        order = np.argsort(-d, kind="stable")[:TOP_JUMPS]
        jumps = [_jump(a, int(q)) for q in order if d[q] > 0]
        out["jumps"] = jumps
        out["max_jump"] = rounded(d.max())
        if max_jump is not None:
            out["over"] = [_jump(a, int(q)) for q in np.nonzero(d > max_jump)[0]]
        return out


def _jump(a: np.ndarray, q: int) -> dict:
    return {"layer": q, "from": rounded(a[q - 1]), "to": rounded(a[q]), "jump": rounded(a[q] - a[q - 1])}


def estimate(grid: SliceGrid, grey: list, settings: PrintSettings | None) -> dict:
    """Print time and resin of a stack.

    Counted from the lowest layer with a solid pixel to the highest (the
    printed layers): the exposures (bottom layers first) plus a fixed time
    per layer for lift and retract (the printer's ``layer_overhead``; 8 s
    without a profile), and the resin as the grey-weighted voxel volume.
    Without settings the defaults of :class:`formats.printers.PrintSettings`
    are used.

    This small estimate is the check's own; it should switch to the shared
    print-time and resin estimate of the printer formats when that exists.

    Returns
    -------
    dict
        ``layers`` (printed), ``print_seconds``, ``resin_ml``, ``exposure``,
        ``bottom_exposure``, ``bottom_layers``, ``layer_overhead`` (s) and
        ``assumed`` (True when no printer or exposure was given).
    """
    s = settings if settings is not None else PrintSettings(None, grid.layer_height)
    g = np.asarray(grey, dtype=np.float64)
    solid = np.nonzero(g > 0)[0]
    n = int(solid[-1] - solid[0] + 1) if solid.size else 0
    overhead = s.printer.layer_overhead if s.printer is not None else DEFAULT_LAYER_OVERHEAD
    bottom = min(s.bottom_layers, n)
    seconds = bottom * s.bottom_exposure + (n - bottom) * s.exposure + n * overhead
    px, py = grid.pixel_size
    ml = float(g.sum()) * px * py * grid.layer_height / 1000.0
    return {"layers": n, "print_seconds": rounded(seconds), "resin_ml": rounded(ml), "exposure": s.exposure,
            "bottom_exposure": s.bottom_exposure, "bottom_layers": s.bottom_layers, "layer_overhead": overhead,
            "assumed": settings is None or s.printer is None}


__all__ = ["AreaStats", "estimate", "TOP_JUMPS"]
