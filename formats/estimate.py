"""Print time and resin volume: the one estimate every format stores and the CLI prints.

Time model
----------
A resin printer repeats the same cycle for every layer ``k``::

    t_k = e_k + w + m + s_k

* ``e_k``: the exposure, s. ``bottom_exposure`` for the first
  ``bottom_layers`` layers and ``exposure`` after them; with ``fade`` (Prusa's
  faded layers) the first ``f = min(bottom_layers, layers)`` exposures run
  linearly from ``bottom_exposure`` down toward ``exposure``:
  ``e_k = b - (b - e) k / f``.
* ``w``: the printer's fixed time per layer, s (:attr:`Printer.layer_overhead`):
  the wait before and after curing that the file stores (Anycubic "wait before
  cure", Chitu "light-off delay"); for Prusa printers, which tilt the vat
  instead of lifting, the fast tilt and settle time.
* ``m``: the lift and retract moves, ``60 (d_lift / v_lift + d_retract /
  v_retract)`` s for distances in mm and speeds in mm/min
  (:attr:`Printer.lift`; zero distances on tilting printers).
* ``s_k``: :attr:`Printer.slow_overhead` for a layer whose solid area
  (pixels >= 128) exceeds :data:`AREA_FILL` % of the display (Prusa's slow
  tilt), else 0.

The print time is ``T = sum_k t_k``. Without a printer (a plain stack) only
the exposures count.

Resin volume
------------
``V = sum over layers and pixels of grey / 255 x px x py x h`` (mm³; ml =
V / 1000): every pixel cures in proportion to its grey. With ``--aa`` /
``--aa-z`` and ``--gamma 1`` the grey is the pixel's exact area (XY) or
volume (z) coverage to 1/255, so ``V`` is the exact coverage volume of the
model, to half a grey level per edge pixel; without anti-aliasing it is the
volume of the voxels whose centre is inside.

Formats that store fewer grey levels than 8 bits (CTB: 7 bits, Anycubic: 4
bits or bit planes) keep the estimate of the 8-bit layers they were given.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from formats.rle import occupied

#: percentage of the display above which a layer counts as large (PrusaSlicer ``area_fill``)
AREA_FILL = 50.0
#: resin density for the weight fields of the printer formats, g/ml
RESIN_DENSITY = 1.1


@dataclass(frozen=True)
class PrintEstimate:
    """Print time and resin volume of a layer stack.

    Attributes
    ----------
    layers : int
    exposure : float, s
        Sum of the layer exposures.
    motion : float, s
        Sum of the lift and retract moves.
    waits : float, s
        Sum of the fixed per-layer waits (and slow tilts).
    volume_ml : float or None
        Resin volume, ml; None when the layers are not known (``--dry-run``).
    slow_layers : int
        Layers whose solid area exceeds :data:`AREA_FILL` %.
    """

    layers: int
    exposure: float
    motion: float
    waits: float
    volume_ml: float | None = None
    slow_layers: int = 0

    @property
    def weight_g(self) -> float | None:
        """Resin weight at :data:`RESIN_DENSITY`, g."""
        return None if self.volume_ml is None else self.volume_ml * RESIN_DENSITY

    @property
    def seconds(self) -> float:
        """Total print time, s."""
        return self.exposure + self.motion + self.waits

    def describe(self) -> str:
        """One line for people: ``print time 1 h 02 min (exposure ..., ...); resin 1.234 ml``."""
        parts = [f"exposure {duration(self.exposure)}"]
        if self.motion:
            parts.append(f"lift {duration(self.motion)}")
        if self.waits:
            parts.append(f"waits {duration(self.waits)}")
        text = f"print time {duration(self.seconds)} ({', '.join(parts)}) for {self.layers:,} layers"
        if self.volume_ml is not None:
            text += f"; resin {self.volume_ml:.4g} ml"
        return text

    def to_dict(self) -> dict:
        """JSON-ready fields plus ``seconds``."""
        return {"seconds": self.seconds, "exposure": self.exposure, "motion": self.motion, "waits": self.waits,
                "volume_ml": self.volume_ml, "layers": self.layers, "slow_layers": self.slow_layers}

    @classmethod
    def from_dict(cls, d: dict) -> "PrintEstimate":
        """Inverse of :meth:`to_dict`."""
        return cls(d["layers"], d["exposure"], d["motion"], d["waits"], d["volume_ml"], d["slow_layers"])


def duration(seconds: float) -> str:
    """``3 h 05 min``, ``4 min 07 s``, ``12.5 s``.

    Examples
    --------
    >>> duration(11100.2), duration(247), duration(12.5)
    ('3 h 05 min', '4 min 07 s', '12.5 s')
    """
    s = float(seconds)
    if s < 60:
        return f"{s:.3g} s"
    m, sec = divmod(int(round(s)), 60)
    if m < 60:
        return f"{m} min {sec:02d} s"
    h, m = divmod(int(round(s / 60)), 60)
    return f"{h} h {m:02d} min"


def exposure_times(settings, layers: int, fade: bool = False) -> np.ndarray:
    """Exposure of every layer, s.

    Parameters
    ----------
    settings : formats.printer_profiles.PrintSettings
    layers : int
    fade : bool
        Prusa faded layers: the first ``min(bottom_layers, layers)`` exposures
        fall linearly from ``bottom_exposure`` toward ``exposure``.

    Returns
    -------
    (layers,) float64
    """
    k = np.arange(layers, dtype=np.float64)
    b, e = float(settings.bottom_exposure), float(settings.exposure)
    bottom = min(int(settings.bottom_layers), layers)
    out = np.full(layers, e)
    if fade:
        out[:bottom] = b - (b - e) * k[:bottom] / max(bottom, 1)
    else:
        out[:bottom] = b
    return out


def lift_seconds(printer) -> float:
    """Time of one lift and retract, s: ``60 (d_lift / v_lift + d_retract / v_retract)``."""
    if printer is None:
        return 0.0
    lift_d, lift_v, retract_d, retract_v = printer.lift
    return 60.0 * (lift_d / lift_v + retract_d / retract_v)


def print_estimate(settings, layers: int, grey_sum: int | None = None, slow_layers: int = 0,
                   fade: bool = False, pixel_area: float | None = None) -> PrintEstimate:
    """Print time and resin volume of ``layers`` layers (see the module docstring).

    Parameters
    ----------
    settings : formats.printer_profiles.PrintSettings or None
        Exposures, layer height and printer (None: no estimate possible,
        returns zero times).
    layers : int
    grey_sum : int, optional
        Sum of every layer pixel's grey (0-255); None leaves the volume unknown.
    slow_layers : int
        Layers whose solid area exceeds :data:`AREA_FILL` %.
    fade : bool
        Prusa faded bottom layers (:func:`exposure_times`).
    pixel_area : float, mm², optional
        Area of one layer pixel (default: the printer's).

    Returns
    -------
    PrintEstimate
    """
    if settings is None:
        return PrintEstimate(int(layers), 0.0, 0.0, 0.0, None)
    p = settings.printer
    exposure = float(exposure_times(settings, layers, fade).sum())
    motion = layers * lift_seconds(p)
    waits = 0.0 if p is None else layers * float(p.layer_overhead) + slow_layers * float(p.slow_overhead)
    volume = None
    if grey_sum is not None:
        if pixel_area is None:
            px, py = p.pixel_size
            pixel_area = px * py
        volume = float(grey_sum) / 255.0 * pixel_area * float(settings.layer_height) / 1000.0
    return PrintEstimate(int(layers), exposure, motion, waits, volume, int(slow_layers))


class LayerMeter:
    """What the estimate needs from the layers, gathered as they stream past.

    Attributes
    ----------
    layers : int
    grey_sum : int
        Sum of every pixel's grey over all layers seen (exact, integer).
    slow_layers : int
        Layers whose solid area (grey >= 128) exceeds :data:`AREA_FILL` %.
    """

    def __init__(self):
        self.layers = 0
        self.grey_sum = 0
        self.slow_layers = 0

    def add(self, image: np.ndarray, box=False) -> None:
        """Record one layer, a (h, w) uint8 image.

        ``box``: the image's :func:`formats.rle.occupied` box if known (None:
        empty), so that only it is read; False: found here.
        """
        if box is False:
            box = occupied(image)
        if box is not None:
            r0, r1, c0, c1 = box
            band = image[r0:r1, c0:c1]                      # only the box that holds the model
            # exact: a row of uint8 sums below 2**32 for rows under 16 M pixels
            self.grey_sum += int(band.sum(axis=1, dtype=np.uint32).sum(dtype=np.uint64))
            solid = np.count_nonzero(band >= 128)
            self.slow_layers += bool(solid * 100.0 > AREA_FILL * image.size)
        self.layers += 1

    def estimate(self, settings, fade: bool = False, pixel_area: float | None = None) -> PrintEstimate:
        """The :func:`print_estimate` of the layers seen so far."""
        return print_estimate(settings, self.layers, self.grey_sum, self.slow_layers, fade, pixel_area)


__all__ = ["AREA_FILL", "RESIN_DENSITY", "PrintEstimate", "print_estimate", "exposure_times", "lift_seconds",
           "LayerMeter", "duration"]
