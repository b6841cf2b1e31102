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

from formats.estimate import AREA_FILL, print_estimate
from formats.printer_profiles import PrintSettings

from slicer.tracer.grid import SliceGrid
from slicer.printability.stream import rounded

#: layer-to-layer jumps listed in a report
TOP_JUMPS = 5
#: time per layer besides exposure (lift, tilt) without a printer profile, s


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


def estimate(grid: SliceGrid, grey: list, settings: PrintSettings | None, area: list | None = None) -> dict:
    """Print time and resin of a stack, by the printer formats' own estimate
    (:func:`formats.estimate.print_estimate`).

    Counted from the lowest layer with a solid pixel to the highest (the
    printed layers). Without settings the defaults of
    :class:`formats.printer_profiles.PrintSettings` are used (and ``assumed`` is True).

    Parameters
    ----------
    grid : SliceGrid
        The layers' grid (pixel area).
    grey : list of float
        Per layer, the sum of grey / 255 (voxels).
    settings : PrintSettings or None
    area : list of float, optional, mm²
        Per layer cured area, for the slow-tilt layers of Prusa printers.

    Returns
    -------
    dict
        :meth:`formats.estimate.PrintEstimate.to_dict` plus ``print_seconds``,
        ``resin_ml`` and ``assumed``.
    """
    s = settings if settings is not None else PrintSettings(None, grid.layer_height)
    g = np.asarray(grey, dtype=np.float64)
    solid = np.nonzero(g > 0)[0]
    lo, hi = (int(solid[0]), int(solid[-1]) + 1) if solid.size else (0, 0)
    px, py = grid.pixel_size
    plate = grid.width * grid.height * px * py
    slow = 0 if area is None else int(np.count_nonzero(np.asarray(area[lo:hi]) * 100.0 > AREA_FILL * plate))
    fade = s.printer is not None and s.printer.format in ("sl1", "sl1s")
    est = print_estimate(s, hi - lo, grey_sum=int(round(float(g.sum()) * 255.0)), slow_layers=slow, fade=fade,
                         pixel_area=px * py)
    return {**est.to_dict(), "print_seconds": rounded(est.seconds), "resin_ml": rounded(est.volume_ml),
            "assumed": settings is None or s.printer is None}


__all__ = ["AreaStats", "estimate", "TOP_JUMPS"]
