"""The printability check: one pass over the layer stream, one report.

:func:`check_stack` feeds every layer of a :class:`~.stream.LayerStack` to
the island, trap and area accumulators (and to an optional callback, so a
preview can encode the same layers on the way), measures the struts of the
scene when it is known, and returns a :class:`CheckReport`. What blocks a
print is configurable (:attr:`CheckOptions.fail_on`).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from slicer.atomic import write_bytes
from slicer.arguments import choice, number
from slicer.errors import OptionError
from slicer.printability.areas import AreaStats, estimate
from slicer.printability.islands import Island, IslandFinder
from slicer.printability.stream import SOLID, LayerStack
from slicer.printability.thin import ThinSegment, thin_segments
from slicer.printability.traps import Trap, TrapFinder

#: finding kinds that ``--fail-on`` may name
KINDS = ("islands", "thin", "traps", "jumps")
#: what blocks by default
DEFAULT_FAIL_ON = ("islands", "thin", "traps")
#: findings listed per kind in the text report
LISTED = 10


@dataclass(frozen=True)
class CheckOptions:
    """Thresholds of the check.

    Attributes
    ----------
    min_feature : float, mm
        Struts printed thinner than this (or than the pixel pitch) are reported.
    min_island_area : float, mm²
        Islands smaller than this are reported but do not block.
    min_trap_volume : float, mm³
        Traps smaller than this are reported but do not block.
    max_area_jump : float or None, mm²
        Report layer-to-layer area increases above this as ``jumps`` findings.
    fail_on : tuple of str
        Kinds of findings that block (``islands``, ``thin``, ``traps``, ``jumps``).
    """

    min_feature: float = 0.0
    min_island_area: float = 0.0
    min_trap_volume: float = 0.0
    max_area_jump: float | None = None
    fail_on: tuple[str, ...] = DEFAULT_FAIL_ON

    @classmethod
    def from_values(cls, min_feature=0.0, min_island_area=0.0, min_trap_volume=0.0, max_area_jump=None,
                    fail_on=DEFAULT_FAIL_ON) -> "CheckOptions":
        """Validated options (OptionError naming the option)."""
        if isinstance(fail_on, str):
            fail_on = [f for f in fail_on.replace(" ", "").split(",") if f]
        kinds = []
        for f in fail_on:
            if str(f).lower() == "none":
                continue
            kinds.append(choice(f, KINDS + ("none",), "--fail-on kind", OptionError))
        return cls(number(min_feature, "--min-feature", lo=0.0), number(min_island_area, "--min-island-area", lo=0.0),
                   number(min_trap_volume, "--min-trap-volume", lo=0.0),
                   None if max_area_jump is None else number(max_area_jump, "--max-area-jump", lo=0.0),
                   tuple(dict.fromkeys(kinds)))


@dataclass
class CheckReport:
    """What the check found.

    Attributes
    ----------
    islands : list of Island
    thin_segments : list of ThinSegment or None
        None when no scene was given (a stack read back from an output).
    traps : list of Trap
    areas : dict
        :meth:`AreaStats.summary`.
    estimate : dict
        :func:`~.areas.estimate`.
    blocking : dict
        Kind -> number of blocking findings (only kinds that block and have some).
    info : dict
        Grid, frame, printer, source, thresholds.
    """

    islands: list[Island]
    thin_segments: list[ThinSegment] | None
    traps: list[Trap]
    areas: dict
    estimate: dict
    options: CheckOptions
    info: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict:
        """Findings per kind (blocking or not)."""
        return {"islands": len(self.islands), "thin": len(self.thin_segments or []), "traps": len(self.traps),
                "jumps": len(self.areas.get("over", []))}

    @property
    def blocking(self) -> dict:
        o = self.options
        n = {"islands": sum(i.area >= o.min_island_area for i in self.islands),
             "thin": len(self.thin_segments or []),
             "traps": sum(t.volume >= o.min_trap_volume for t in self.traps),
             "jumps": len(self.areas.get("over", []))}
        return {k: int(n[k]) for k in o.fail_on if n[k]}

    @property
    def clean(self) -> bool:
        """Nothing found at all."""
        return not any(self.counts.values())

    @property
    def ok(self) -> bool:
        """Nothing blocking."""
        return not self.blocking

    def to_dict(self) -> dict:
        return {
            "skelslice": self.info,
            "ok": self.ok,
            "blocking": self.blocking,
            "fail_on": list(self.options.fail_on),
            "islands": [i.to_dict() for i in self.islands],
            "thin_segments": None if self.thin_segments is None else [t.to_dict() for t in self.thin_segments],
            "traps": [t.to_dict() for t in self.traps],
            "areas": self.areas,
            "estimate": self.estimate,
        }

    def write_json(self, path, force: bool = False) -> None:
        """The report as JSON (:meth:`to_dict`), written atomically."""
        write_bytes(path, (json.dumps(self.to_dict(), indent=1) + "\n").encode(), force)

    def text(self, listed: int = LISTED) -> str:
        """A report for people: findings (at most ``listed`` per kind), then the summary."""
        src = self.info.get("source") or "the job"
        unit = "plate" if self.info.get("frame") == "plate" else "scene"
        lines = []
        b = self.blocking
        if b:
            lines.append(f"{src}: not printable as is: " + ", ".join(f"{n} {k}" for k, n in b.items()))
        elif not self.clean:
            lines.append(f"{src}: nothing blocks printing; notes:")
        lines += _listed([f"island   layer {i.layer} (z {mm_text(i.z)} mm) at x {mm_text(i.x)} y {mm_text(i.y)} mm "
                          f"({unit}), {i.area:.4g} mm², held by nothing below" for i in self.islands], listed, "islands")
        lines += _listed([f"thin     segment {t.segment}: printed width {t.width:.4g} mm < {t.threshold:.4g} mm "
                          f"(2 x radius {t.radius_width:.4g} mm) at x {mm_text(t.x)} y {mm_text(t.y)} "
                          f"z {mm_text(t.z)} mm" for t in self.thin_segments or []], listed, "thin segments")
        lines += _listed([f"trap     {'closed cavity' if t.kind == 'closed' else 'suction cup (open to the plate only)'}"
                          f", {t.volume:.4g} mm³ at x {mm_text(t.x)} y {mm_text(t.y)} z {mm_text(t.z)} mm, "
                          f"layers {t.layers[0]}-{t.layers[1]}" for t in self.traps], listed, "traps")
        lines += _listed([f"jump     layer {j['layer']}: area {j['from']:.4g} -> {j['to']:.4g} mm² "
                          f"(+{j['jump']:.4g} mm²)" for j in self.areas.get("over", [])], listed, "jumps")
        if lines:
            lines.append(self.summary_line())
        return "\n".join(lines)

    def summary_line(self) -> str:
        a, e = self.areas, self.estimate
        big = a.get("largest")
        parts = []
        if big:
            parts.append(f"largest layer {big['area']:.4g} mm² (layer {big['layer']})")
            parts.append(f"largest jump {a['max_jump']:.4g} mm²")
        t = e["print_seconds"]
        parts.append(f"{e['layers']} layers, about {int(t // 3600)} h {int(t % 3600 // 60):02d} min"
                     + (" (default exposures)" if e["assumed"] else ""))
        parts.append(f"resin {e['resin_ml']:.3g} ml")
        return "summary: " + "; ".join(parts)


def mm_text(v: float) -> str:
    """A length for people: 4 decimals at most, no -0."""
    return f"{round(float(v), 4) + 0.0:g}"


def _listed(items: list[str], n: int, what: str) -> list[str]:
    if len(items) <= n:
        return items
    return items[:n] + [f"         ... and {len(items) - n} more {what} (all of them in --json)"]


def check_stack(stack: LayerStack, skel=None, options: CheckOptions | None = None, on_layer=None,
                blend: str = "sum") -> CheckReport:
    """Check a layer stack (one pass) and, with the scene, its struts.

    Parameters
    ----------
    stack : LayerStack
    skel : Skeleton, optional
        The scene that was sliced (enables the thin-strut check).
    options : CheckOptions, optional
    on_layer : callable, optional
        Called as ``on_layer(k, image)`` with every layer, in order.
    blend : {"sum", "union"}
        The field the scene was sliced with (the thin-strut widths are measured on it).

    Returns
    -------
    CheckReport
    """
    o = options or CheckOptions()
    g = stack.grid
    islands, traps, areas = IslandFinder(g), TrapFinder(g), AreaStats(g)
    n = 0
    for k, img in enumerate(stack):
        img = np.asarray(img)
        if img.shape != (g.height, g.width):
            raise OptionError(f"{stack.source}: layer {k} is {img.shape[1]} x {img.shape[0]} px, "
                              f"expected {g.width} x {g.height}")
        solid = np.ascontiguousarray(img >= SOLID)
        islands.add(k, solid)
        traps.add(k, solid)
        areas.add(k, solid, img)
        if on_layer is not None:
            on_layer(k, img)
        n += 1
    px, py = g.pixel_size
    pitch = max(px, py)
    threshold = max(pitch, o.min_feature)
    thin = None
    if skel is not None:
        thin = thin_segments(skel, threshold, stack.offset, stack.layer_of, blend)
    info = {"source": stack.source, "frame": stack.frame, "grid": {**g.to_dict(), "layers": n},
            "window": list(stack.window), "full_shape": list(stack.full_shape),
            "printer": stack.printer.name if stack.printer is not None else None,
            "solid_grey": SOLID, "thin_threshold": threshold, "pixel_pitch": pitch,
            "options": {"min_feature": o.min_feature, "min_island_area": o.min_island_area,
                        "min_trap_volume": o.min_trap_volume, "max_area_jump": o.max_area_jump}}
    return CheckReport(islands.islands, thin, traps.finish(), areas.summary(o.max_area_jump),
                       estimate(g, areas.grey, stack.settings, areas.area), o, info)


__all__ = ["CheckOptions", "CheckReport", "check_stack", "mm_text", "KINDS", "DEFAULT_FAIL_ON"]
