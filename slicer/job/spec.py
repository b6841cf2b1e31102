"""A slicing job as data: grid, tracing, printing, output and scale-out settings.

:class:`SliceJob` is what :func:`slicer.job.run.run_slice` takes; the ``slice``
command builds one from its flags (and ``--config`` files feed the same
flags), and Python callers build one directly or from option names with
:meth:`SliceJob.from_options`. :meth:`SliceJob.resolve` checks how the
options combine — before any work — and says what to trace and write
(:class:`ResolvedJob`).

Examples
--------
>>> job = SliceJob.from_options(pixel_size=0.05, aa=2)
>>> job.grid.pixel_size, job.printing.aa
(0.05, 2)
>>> r = job.resolve("out.zip")
>>> r.fmt, r.pitch, r.layer_height
('zip', (0.025, 0.025), 0.05)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from formats import format_for, writer_for
from formats.printer_profiles import PRINTERS, Printer, PrintSettings, get_printer

from slicer.raster.antialias import check_aa, is_exact
from slicer.model.blend import require_sum, require_traceable
from slicer.arguments import MAX_COUNT, coordinates, fmt_num, integer, magnitude
from slicer.errors import OptionError
from slicer.tracer.slicing import METHODS
from slicer.scale.tileplan import parse_size
from slicer.scale.tiletask import TraceOptions


@dataclass(frozen=True)
class GridOptions:
    """Where the voxel centres are.

    Attributes
    ----------
    pixel_size : float or None, mm
        Pitch along x (and y); required without a printer, refused with one.
    pixel_size_y : float or None, mm
        Pitch along y (default: ``pixel_size``).
    layer_height : float or None, mm
        Default: the pixel size, or the printer's layer height.
    bounds : (6,) float or None, mm
        ``X0 Y0 Z0 X1 Y1 Z1``; default: the model plus one empty voxel.
    """

    pixel_size: float | None = None
    pixel_size_y: float | None = None
    layer_height: float | None = None
    bounds: tuple[float, float, float, float, float, float] | None = None


@dataclass(frozen=True)
class PrintOptions:
    """Printer placement, anti-aliasing and exposure.

    Attributes
    ----------
    printer : str or None
        A profile name (``skelslice printers``).
    at : (2,) float or None, plate mm
        Centre of the model's footprint on the plate (default: plate centre).
    aa : int
        XY supersampling, N x N sub-pixels (1: none).
    aa_z : bool
        Exact sub-layer coverage.
    gamma : float
        Coverage-to-grey exponent.
    exposure, bottom_exposure : float or None, s
    bottom_layers : int or None
    """

    printer: str | None = None
    at: tuple[float, float] | None = None
    aa: int = 1
    aa_z: bool = False
    gamma: float = 1.0
    exposure: float | None = None
    bottom_exposure: float | None = None
    bottom_layers: int | None = None


@dataclass(frozen=True)
class OutputOptions:
    """What is written besides the layers, and how.

    Attributes
    ----------
    fmt : str or None
        Format name (default: from the output's suffix, else the printer's, else png).
    force : bool
        Replace an existing output (never the input).
    contour_tol : float, mm
        Accuracy of contour vertices (contour formats, ``contours``).
    contours : path or None
        Also write the layer contours to this ``.geojson`` / ``.json`` file.
    scene_name : str or None
        Recorded as provenance.
    """

    fmt: str | None = None
    force: bool = False
    contour_tol: float = 1e-3
    contours: str | None = None
    scene_name: str | None = None


@dataclass(frozen=True)
class ScaleOptions:
    """Memory budget, tiles, slabs and where tiles run.

    Attributes
    ----------
    max_memory : int, str or None
        Budget in bytes or as text (``"4GB"``); None: no limit.
    executor : str or None
        ``serial``, ``threads``, ``processes`` or ``dask``; None: in this
        process without planning (unless a plan is needed anyway).
    workers : int or None
    scheduler : str or None
        A running Dask scheduler's address.
    tile : int or None, px
    slab : int or None, layers
    prefetch : bool or None
        With several slabs, trace the next one while one is written
        (:attr:`slicer.scale.tileplan.TilePlan.prefetch`): True sizes the slabs so
        that two fit the budget; None (default) prefetches only when two
        slabs of the size planned without it fit; False never.
    """

    max_memory: int | str | None = None
    executor: str | None = None
    workers: int | None = None
    scheduler: str | None = None
    tile: int | None = None
    slab: int | None = None
    prefetch: bool | None = None

    @property
    def planned(self) -> bool:
        """True when any setting asks for tiles and slabs (:mod:`slicer.scale.tiles`)."""
        return any(v is not None for v in (self.max_memory, self.executor, self.tile, self.slab))


#: option name -> (group attribute, field name); the flat names the CLI and ``--config`` use
_GROUPS = {"grid": GridOptions, "trace": TraceOptions, "printing": PrintOptions, "output": OutputOptions,
           "scale": ScaleOptions}
_DERIVED = {"spans", "span_tol"}      # TraceOptions fields the job sets itself (from --aa-z)


def _option_map() -> dict[str, tuple[str, str]]:
    out = {}
    for group, cls in _GROUPS.items():
        for f in dataclasses.fields(cls):
            if group == "trace" and f.name in _DERIVED:
                continue
            out[f.name] = (group, f.name)
    return out


OPTIONS: dict[str, tuple[str, str]] = _option_map()


@dataclass(frozen=True)
class ResolvedJob:
    """What a checked job traces and writes.

    Attributes
    ----------
    fmt : str
        Output format name.
    settings : PrintSettings or None
        None for a plain stack (no printer, no anti-aliasing, no exposure options).
    pitch : (2,) float, mm
        Pixel pitch to trace at (output pitch / aa).
    layer_height : float, mm
    spans : bool
        Trace with real-valued inside spans (``aa_z``).
    """

    fmt: str
    settings: PrintSettings | None
    pitch: tuple[float, float]
    layer_height: float
    spans: bool = False

    @property
    def printer(self) -> Printer | None:
        return None if self.settings is None else self.settings.printer


@dataclass(frozen=True)
class SliceJob:
    """A whole slicing job's settings (everything but the scene and the output path).

    Attributes
    ----------
    grid : GridOptions
    trace : slicer.scale.tiletask.TraceOptions
        Method, bucket, threads, strict (spans are set from ``printing.aa_z``).
    printing : PrintOptions
    output : OutputOptions
    scale : ScaleOptions
    """

    grid: GridOptions = field(default_factory=GridOptions)
    trace: TraceOptions = field(default_factory=TraceOptions)
    printing: PrintOptions = field(default_factory=PrintOptions)
    output: OutputOptions = field(default_factory=OutputOptions)
    scale: ScaleOptions = field(default_factory=ScaleOptions)

    @classmethod
    def from_options(cls, **options) -> "SliceJob":
        """A job from flat option names (``pixel_size=0.05, printer="prusa-sl1s", ...``).

        Names are the ``slice`` command's options with underscores
        (:data:`OPTIONS`); ``None`` values keep the defaults.

        Raises
        ------
        OptionError
            An unknown option name.
        """
        groups: dict[str, dict] = {g: {} for g in _GROUPS}
        for name, value in options.items():
            key = OPTIONS.get(name.replace("-", "_"))
            if key is None:
                raise OptionError(f"unknown slicing option {name!r}; known options: {', '.join(sorted(OPTIONS))}")
            if value is not None:
                groups[key[0]][key[1]] = _normalise(key[1], value)
        return cls(**{g: _GROUPS[g](**kw) for g, kw in groups.items()})

    def replace(self, **options) -> "SliceJob":
        """A copy with some flat options changed (see :meth:`from_options`)."""
        return SliceJob.from_options(**{**self.to_options(), **options})

    def to_options(self) -> dict:
        """The flat option names and values of this job (inverse of :meth:`from_options`)."""
        return {name: getattr(getattr(self, g), f) for name, (g, f) in OPTIONS.items()}

    def resolve(self, out) -> ResolvedJob:
        """Check how the options combine, before any work.

        The format is ``output.fmt``, else the output's suffix, else the
        printer's default format, else ``png``. ``sl1``/``sl1s`` without a
        printer use the Prusa SL1/SL1S profile; formats that need a printer
        refuse to run without one. With a printer, the pixel pitch and default
        layer height come from the profile and ``pixel_size``/``bounds`` are
        refused.

        Raises
        ------
        OptionError
            Conflicting or invalid options (naming them).
        FormatError
            The format cannot hold the job (its own limits).
        OutputError
            Unknown format.
        """
        g, p, t = self.grid, self.printing, self.trace
        _check_trace(t)
        self._check_scale()
        prn = get_printer(p.printer) if p.printer is not None else None
        name = format_for(self.output.fmt, out, prn.format if prn is not None else "png")
        cls = writer_for(name, out)
        if t.blend != "sum":
            if getattr(cls, "kind", "image") == "contours":
                require_sum(t.blend, f"the {name} format (contours refined on the field)")
            if self.output.contours is not None:
                require_sum(t.blend, "--contours (contours refined on the field)")
        if prn is None and cls.default_printer:
            prn = get_printer(cls.default_printer)
        if prn is None and cls.needs_printer:
            raise OptionError(f"the {name} format needs --printer NAME; choose one of "
                              f"{', '.join(sorted(PRINTERS))}")
        aa, gamma = check_aa(p.aa, p.gamma)
        magnitude(self.output.contour_tol, "--contour-tol", positive=True)
        if prn is None and p.at is not None:
            raise OptionError("--at needs --printer (it places the model on a printer's plate)")
        px, py, h = _pitch(g, prn)
        settings = None
        exact = is_exact(p.aa)
        if prn is not None or aa > 1 or p.aa_z or exact or any(v is not None for v in
                                                      (p.exposure, p.bottom_exposure, p.bottom_layers)):
            settings = PrintSettings(
                prn, h,
                exposure=_default(p.exposure, "--exposure", prn.exposure if prn else 2.0),
                bottom_exposure=_default(p.bottom_exposure, "--bottom-exposure", prn.bottom_exposure if prn else 25.0),
                bottom_layers=(integer(p.bottom_layers, "--bottom-layers", lo=0) if p.bottom_layers is not None
                               else (prn.bottom_layers if prn else 10)),
                aa=aa, aa_z=bool(p.aa_z), gamma=gamma, aa_exact=exact,
                at=None if p.at is None else _plate_point(p.at, prn))
            check = getattr(cls, "check_settings", None)
            if check is not None:
                check(settings)
        return ResolvedJob(name, settings, (px / aa, py / aa), h, bool(p.aa_z) and not exact)

    def trace_options(self, resolved: ResolvedJob) -> TraceOptions:
        """The tracer settings of this job (spans on with ``aa_z``)."""
        return dataclasses.replace(self.trace, spans=resolved.spans)

    def _check_scale(self) -> None:
        s = self.scale
        if isinstance(s.max_memory, str):
            parse_size(s.max_memory)
        for name, v in (("--workers", s.workers), ("--tile", s.tile), ("--slab", s.slab)):
            if v is not None:
                integer(v, name, lo=1)


def _normalise(name: str, value):
    """Sequences become tuples (frozen dataclasses stay hashable)."""
    if name in ("bounds", "at") and not isinstance(value, (str, bytes)):
        try:
            return tuple(value)
        except TypeError:
            return value
    return value


def _default(value, name: str, default: float) -> float:
    return default if value is None else magnitude(value, name, positive=True, unit="s")


def _plate_point(at, prn: Printer | None) -> tuple[float, float]:
    """``--at X Y``: two finite numbers on the printer's plate (mm)."""
    x, y = coordinates(at, 2, "--at")
    if prn is not None:
        W, H = prn.display
        if not (0.0 <= x <= W and 0.0 <= y <= H):
            raise OptionError(f"--at {fmt_num(x)} {fmt_num(y)} is off the {prn.label} plate "
                              f"(X 0..{W:g}, Y 0..{H:g} mm)")
    return x, y


def _check_trace(t: TraceOptions) -> None:
    if t.method not in METHODS:
        raise OptionError(f"unknown method {t.method!r}; choose one of {', '.join(sorted(METHODS))}")
    require_traceable(t.blend, method=t.method)
    integer(t.bucket, "--bucket", lo=0, hi=MAX_COUNT)
    if t.threads is not None:
        integer(t.threads, "--threads", lo=1, hi=MAX_COUNT)


def _pitch(g: GridOptions, prn: Printer | None) -> tuple[float, float, float]:
    """Output pixel pitch (x, y) and layer height, mm."""
    if prn is not None:
        if g.pixel_size is not None or g.pixel_size_y is not None:
            raise OptionError(f"--pixel-size cannot be combined with a printer ({prn.name} has "
                              f"{prn.pixel_size[0]:g} x {prn.pixel_size[1]:g} mm pixels)")
        if g.bounds is not None:
            raise OptionError("--bounds cannot be combined with a printer: the model is placed on the plate "
                              "(use --at X Y)")
        px, py = prn.pixel_size
        h = _size(g.layer_height, "layer height") if g.layer_height is not None else prn.layer_height
        return px, py, h
    if g.pixel_size is None:
        raise OptionError("--pixel-size is required without --printer")
    px = _size(g.pixel_size, "pixel size")
    py = _size(g.pixel_size_y, "pixel size y") if g.pixel_size_y is not None else px
    h = _size(g.layer_height, "layer height") if g.layer_height is not None else px
    if g.bounds is not None:
        coordinates(g.bounds, 6, "--bounds")
    return px, py, h


def _size(value, name: str) -> float:
    return magnitude(value, name, positive=True)


__all__ = ["SliceJob", "GridOptions", "TraceOptions", "PrintOptions", "OutputOptions", "ScaleOptions",
           "ResolvedJob", "OPTIONS"]
