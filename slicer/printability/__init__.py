"""Printability check of a sliced job: islands, thin struts, resin traps, layer areas.

Consumers of the layer stream (never re-slicing): a traced result's output
layers (:func:`model_layers`) or an output read back
(:mod:`formats.readback`) go through :func:`check_stack` once.

========================  ====================================================
``islands``               regions of a layer held by nothing below (:mod:`.islands`)
``thin_segments``         struts printed thinner than the pixel or ``min_feature`` (:mod:`.thin`)
``traps``                 closed cavities and suction cups (:mod:`.traps`)
``areas``, ``estimate``   largest layer, area jumps, print time and resin (:mod:`.areas`)
========================  ====================================================
"""
from __future__ import annotations

from slicer.printability.areas import AreaStats, estimate
from slicer.printability.islands import Island, IslandFinder
from slicer.printability.report import DEFAULT_FAIL_ON, KINDS, CheckOptions, CheckReport, check_stack
from slicer.printability.stream import SOLID, LayerStack, model_layers, read_layers
from slicer.printability.thin import ThinSegment, printed_widths, thin_segments
from slicer.printability.traps import Trap, TrapFinder

__all__ = ["LayerStack", "model_layers", "read_layers", "SOLID", "check_stack", "CheckOptions", "CheckReport", "KINDS",
           "DEFAULT_FAIL_ON", "Island", "IslandFinder", "Trap", "TrapFinder", "ThinSegment", "printed_widths",
           "thin_segments", "AreaStats", "estimate"]
