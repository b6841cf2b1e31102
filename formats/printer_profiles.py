"""Built-in resin printer profiles and model placement on the build plate.

Plate coordinates
-----------------
``X`` runs along the display's ``pixels[0]`` axis over ``[0, display[0]]`` mm,
``Y`` along ``pixels[1]`` over ``[0, display[1]]`` mm, seen from above, with
the build plate at ``Z = 0`` (PrusaSlicer's ``bed_shape``). A *plate image*
has the grid conventions of :class:`slicer.tracer.grid.SliceGrid`: ``pixels[0]``
columns toward +X, ``pixels[1]`` rows toward -Y, so pixel ``(row j, column
i)`` has its centre at ``X = (i + 1/2) px``, ``Y = display[1] - (j + 1/2) py``.

Native images
-------------
Printer files store what the LCD shows. :meth:`Printer.to_native` turns a
plate image into that layout with PrusaSlicer's raster transform
(``SL1Archive::create_raster`` / ``RasterBase::Trafo``; docs/formats.md §1.2):
a portrait display swaps X and Y, ``mirror_x' = portrait XOR mirror_x``,
``mirror_y' = not mirror_y``, raster row 0 at the top. For the SL1S
(portrait, mirror_x) that gives column = Y/py and row = 2560 - X/px, the
measured PrusaSlicer output.

Profile values (resolution, display size, orientation, mirroring, height)
come from PrusaSlicer's ``PrusaResearchSLA.ini`` (Prusa) and UVtools'
``PrusaSlicer/printer/*.ini`` (Elegoo, Phrozen, Creality, Anycubic), which
also give the lift distances and speeds, the per-layer waits and each
printer's native file format (``FILEFORMAT_*``; docs/printers.md). Exposure
times and bottom layers are typical starting values for a standard resin at
0.05 mm: calibrate them for your resin (``--exposure``,
``--bottom-exposure``, ``--bottom-layers``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slicer.errors import GridError, OptionError, OutputError
from slicer.tracer.grid import SliceGrid


@dataclass(frozen=True)
class Printer:
    """One resin printer.

    Attributes
    ----------
    name : str
        Key used by ``--printer``.
    label : str
        Human-readable name (PrusaSlicer ``printer_settings_id`` style).
    vendor : str
    pixels : (2,) int
        ``display_pixels_x``, ``display_pixels_y``.
    display : (2,) float, mm
        ``display_width``, ``display_height``; pixel pitch is
        ``display / pixels`` per axis (non-square allowed).
    orientation : {"landscape", "portrait"}
    mirror_x, mirror_y : bool
        ``display_mirror_x``, ``display_mirror_y``.
    max_height : float, mm
        Highest printable Z.
    layer_height : float, mm
        Default layer height.
    exposure, bottom_exposure : float, s
        Default normal and bottom (first layers) exposure.
    bottom_layers : int
        Default number of bottom layers (Prusa: faded layers).
    format : str
        Default output format name.
    model : str
        Machine code written into the file (Prusa ``printerModel``, GOO
        ``printer_name``).
    thumbnails : tuple of (w, h)
        Preview sizes the format stores.
    lift : (4,) float
        Lift distance (mm), lift speed (mm/min), retract distance (mm),
        retract speed (mm/min), for formats that store motion and for the
        print-time estimate (:mod:`formats.estimate`). Prusa printers tilt
        the vat instead: their lift distances are 0.
    layer_overhead : float, s
        Fixed time per layer besides exposure and lift: the wait before
        curing the file stores (Anycubic "wait before cure", Chitu "light-off
        delay"); for Prusa printers the tilt and settle time.
    slow_overhead : float, s
        Extra time of a layer whose solid area exceeds
        :data:`formats.estimate.AREA_FILL` % of the display (Prusa's slow
        tilt); 0 for lifting printers.
    """

    name: str
    label: str
    vendor: str
    pixels: tuple[int, int]
    display: tuple[float, float]
    orientation: str
    mirror_x: bool
    mirror_y: bool
    max_height: float
    layer_height: float
    exposure: float
    bottom_exposure: float
    bottom_layers: int
    format: str
    model: str
    thumbnails: tuple[tuple[int, int], ...] = ((400, 400), (800, 480))
    lift: tuple[float, float, float, float] = (5.0, 65.0, 5.0, 150.0)
    layer_overhead: float = 8.0
    slow_overhead: float = 0.0

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(px, py) mm: pitch along plate X and Y."""
        return (self.display[0] / self.pixels[0], self.display[1] / self.pixels[1])

    @property
    def plate_shape(self) -> tuple[int, int]:
        """(rows, columns) of a plate image."""
        return (self.pixels[1], self.pixels[0])

    @property
    def native_size(self) -> tuple[float, float]:
        """(width, height) mm of the display along the stored image's columns and rows."""
        if self.orientation == "portrait":
            return (self.display[1], self.display[0])
        return self.display

    @property
    def native_shape(self) -> tuple[int, int]:
        """(rows, columns) of the image stored in the file."""
        if self.orientation == "portrait":
            return (self.pixels[0], self.pixels[1])
        return (self.pixels[1], self.pixels[0])

    def to_native(self, plate: np.ndarray) -> np.ndarray:
        """The file's image of a plate image (a view; no copy).

        Parameters
        ----------
        plate : (pixels[1], pixels[0]) array
            Columns toward +X, rows toward -Y.

        Returns
        -------
        (native_shape) array
        """
        if plate.shape != self.plate_shape:
            raise OutputError(f"{self.name}: plate image must be {self.plate_shape}, got {plate.shape}")
        if self.orientation == "portrait":
            img = plate.T                    # row = X index, column = Y index from the top
            if self.mirror_x:                # mirror_x' false: column = Y / py from Y = 0
                img = img[:, ::-1]
            if not self.mirror_y:            # mirror_y' true: row = H - X / px
                img = img[::-1, :]
            return img
        img = plate
        if self.mirror_x:
            img = img[:, ::-1]
        if self.mirror_y:
            img = img[::-1, :]
        return img

    def native_box(self, box: tuple[int, int, int, int] | None) -> tuple[int, int, int, int] | None:
        """Where a box of a plate image lands in :meth:`to_native`'s image.

        Parameters
        ----------
        box : (r0, r1, c0, c1) or None
            Half-open rows and columns of the plate image (None: empty).

        Returns
        -------
        (r0, r1, c0, c1) or None
            The same pixels' box in the native image.
        """
        if box is None:
            return None
        r0, r1, c0, c1 = box
        rows, cols = self.plate_shape
        if self.orientation == "portrait":
            r0, r1, c0, c1, rows, cols = c0, c1, r0, r1, cols, rows
            flip_c, flip_r = self.mirror_x, not self.mirror_y
        else:
            flip_c, flip_r = self.mirror_x, self.mirror_y
        if flip_c:
            c0, c1 = cols - c1, cols - c0
        if flip_r:
            r0, r1 = rows - r1, rows - r0
        return r0, r1, c0, c1

    def from_native(self, native: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_native`: the plate image of a file's image."""
        img = native
        if self.orientation == "portrait":
            if not self.mirror_y:
                img = img[::-1, :]
            if self.mirror_x:
                img = img[:, ::-1]
            return img.T
        if self.mirror_y:
            img = img[::-1, :]
        if self.mirror_x:
            img = img[:, ::-1]
        return img

    def describe(self) -> str:
        px, py = self.pixel_size
        return (f"{self.name}: {self.label}, {self.pixels[0]} x {self.pixels[1]} px, "
                f"{self.display[0]:g} x {self.display[1]:g} x {self.max_height:g} mm, "
                f"pixel {px * 1000:.4g} x {py * 1000:.4g} um, {self.orientation}"
                f"{', mirror x' if self.mirror_x else ''}{', mirror y' if self.mirror_y else ''}; "
                f"default format {self.format}")


#: name -> Printer
PRINTERS: dict[str, Printer] = {p.name: p for p in [
    # Prusa: tilting vat (no lift); fast tilt + settle per layer, +3 s for a slow tilt
    Printer("prusa-sl1", "Original Prusa SL1", "Prusa", (2560, 1440), (120.96, 68.04), "portrait",
            True, False, 150.0, 0.05, 6.0, 35.0, 10, "sl1", "SL1", lift=(0.0, 65.0, 0.0, 150.0),
            layer_overhead=11.0, slow_overhead=3.0),
    Printer("prusa-sl1s", "Original Prusa SL1S SPEED", "Prusa", (2560, 1620), (128.0, 81.0), "portrait",
            True, False, 150.0, 0.05, 2.0, 25.0, 10, "sl1s", "SL1S", lift=(0.0, 65.0, 0.0, 150.0),
            slow_overhead=3.0),
    # Elegoo GOO (the GOO file's waits are 0)
    Printer("elegoo-mars-4-ultra", "ELEGOO Mars 4 Ultra", "Elegoo", (8520, 4320), (153.36, 77.76),
            "landscape", True, False, 165.0, 0.05, 2.5, 30.0, 5, "goo", "ELEGOO Mars 4 Ultra",
            thumbnails=((290, 290), (116, 116)), lift=(5.0, 100.0, 5.0, 150.0), layer_overhead=0.0),
    Printer("elegoo-saturn-3-ultra", "ELEGOO Saturn 3 Ultra", "Elegoo", (11520, 5120), (218.88, 122.88),
            "landscape", True, False, 260.0, 0.05, 2.5, 30.0, 5, "goo", "ELEGOO Saturn 3 Ultra",
            thumbnails=((290, 290), (116, 116)), lift=(7.0, 70.0, 7.0, 210.0), layer_overhead=0.0),
    # Chitu firmware reading plain CTB v3 (UVtools FILEFORMAT_CTB FILEVERSION_3; light-off delay 0)
    Printer("elegoo-saturn", "ELEGOO Saturn", "Elegoo", (3840, 2400), (192.0, 120.0), "landscape",
            True, False, 200.0, 0.05, 2.5, 35.0, 5, "ctb", "ELEGOO SATURN",
            thumbnails=((400, 300), (200, 125)), lift=(7.0, 70.0, 7.0, 210.0), layer_overhead=0.0),
    Printer("phrozen-sonic-mini-4k", "Phrozen Sonic Mini 4K", "Phrozen", (3840, 2160), (134.4, 75.6),
            "landscape", True, False, 130.0, 0.05, 2.0, 30.0, 5, "ctb", "Phrozen Sonic Mini 4K",
            thumbnails=((400, 300), (200, 125)), lift=(5.0, 65.0, 5.0, 150.0), layer_overhead=0.0),
    Printer("phrozen-sonic-mighty-4k", "Phrozen Sonic Mighty 4K", "Phrozen", (3840, 2400), (199.68, 124.8),
            "landscape", True, False, 220.0, 0.05, 2.5, 35.0, 5, "ctb", "Phrozen Sonic Mighty 4K",
            thumbnails=((400, 300), (200, 125)), lift=(6.0, 60.0, 6.0, 150.0), layer_overhead=0.0),
    Printer("creality-ld-002h", "Creality LD-002H", "Creality", (1620, 2560), (82.62, 130.56), "landscape",
            True, False, 160.0, 0.05, 2.5, 40.0, 6, "ctb", "CREALITY LD-002H",
            thumbnails=((400, 300), (200, 125)), lift=(5.0, 50.0, 5.0, 150.0), layer_overhead=0.0),
    # Anycubic Photon Workshop formats (UVtools FILEFORMAT_*; wait before cure 2.5 s)
    Printer("anycubic-photon-s", "Anycubic Photon S", "Anycubic", (1440, 2560), (68.04, 120.96), "landscape",
            True, False, 165.0, 0.05, 8.0, 60.0, 6, "pws", "Photon S", thumbnails=((224, 168),),
            lift=(6.0, 60.0, 6.0, 150.0), layer_overhead=2.5),
    Printer("anycubic-photon-zero", "Anycubic Photon Zero", "Anycubic", (480, 854), (55.4, 98.63), "landscape",
            True, False, 150.0, 0.05, 8.0, 60.0, 6, "pw0", "Photon Zero", thumbnails=((224, 168),),
            lift=(6.0, 60.0, 6.0, 150.0), layer_overhead=2.5),
    Printer("anycubic-photon-mono", "Anycubic Photon Mono", "Anycubic", (1620, 2560), (82.62, 130.56),
            "landscape", True, False, 165.0, 0.05, 2.0, 35.0, 6, "pwmo", "Photon Mono", thumbnails=((224, 168),),
            lift=(6.0, 150.0, 6.0, 150.0), layer_overhead=2.5),
    Printer("anycubic-photon-mono-4k", "Anycubic Photon Mono 4K", "Anycubic", (3840, 2400), (134.4, 84.0),
            "landscape", True, False, 165.0, 0.05, 2.0, 35.0, 6, "pwma", "Photon Mono 4K",
            thumbnails=((224, 168),), lift=(6.0, 150.0, 6.0, 150.0), layer_overhead=2.5),
    Printer("anycubic-photon-mono-x", "Anycubic Photon Mono X", "Anycubic", (3840, 2400), (192.0, 120.0),
            "landscape", True, False, 245.0, 0.05, 2.0, 40.0, 6, "pwmx", "Photon Mono X",
            thumbnails=((224, 168),), lift=(8.0, 120.0, 8.0, 120.0), layer_overhead=2.5),
    Printer("anycubic-photon-mono-x-6k", "Anycubic Photon Mono X 6K", "Anycubic", (5760, 3600), (198.15, 123.84),
            "landscape", True, False, 245.0, 0.05, 2.0, 35.0, 6, "pwmb", "Photon Mono X 6K",
            thumbnails=((224, 168),), lift=(8.0, 120.0, 8.0, 120.0), layer_overhead=2.5),
    Printer("anycubic-photon-mono-m5s", "Anycubic Photon Mono M5s", "Anycubic", (11520, 5120),
            (218.88, 122.88), "landscape", True, False, 200.0, 0.05, 1.5, 25.0, 4, "pm5s",
            "Photon Mono M5s", thumbnails=((224, 168),), lift=(8.0, 120.0, 8.0, 120.0), layer_overhead=2.5),
]}


def get_printer(name: str) -> Printer:
    """The profile called ``name`` (case-insensitive), else a GridError listing them."""
    key = str(name).strip().lower()
    try:
        return PRINTERS[key]
    except KeyError:
        raise OptionError(f"unknown printer {name!r}; choose one of {', '.join(sorted(PRINTERS))}") from None


@dataclass(frozen=True)
class PrintSettings:
    """What a printer format needs besides the images.

    Attributes
    ----------
    printer : Printer or None
        None: no plate (the model's own grid, as without ``--printer``).
    layer_height : float, mm
    exposure, bottom_exposure : float, s
    bottom_layers : int
    aa : int
        XY supersampling factor (1: none).
    aa_z : bool
        Sub-layer z coverage.
    aa_exact : bool
        ``--aa exact``: coverage is the exact area of the section in each
        pixel (``aa`` is then 1).
    gamma : float
        Coverage-to-grey exponent (see :mod:`slicer.raster.antialias`).
    at : (2,) float or None, plate mm
        Where the model's footprint centre goes (None: plate centre).
    """

    printer: Printer | None
    layer_height: float
    exposure: float = 2.0
    bottom_exposure: float = 25.0
    bottom_layers: int = 10
    aa: int = 1
    aa_z: bool = False
    gamma: float = 1.0
    at: tuple[float, float] | None = None
    aa_exact: bool = False

    @property
    def antialiased(self) -> bool:
        return self.aa > 1 or self.aa_z or self.aa_exact

    def exposure_of(self, k: int) -> float:
        """Exposure of layer k, s (bottom layers first)."""
        return self.bottom_exposure if k < self.bottom_layers else self.exposure

    def to_dict(self) -> dict:
        d = {"layer_height": self.layer_height, "exposure": self.exposure,
             "bottom_exposure": self.bottom_exposure, "bottom_layers": self.bottom_layers,
             "aa": "exact" if self.aa_exact else self.aa, "aa_z": self.aa_z, "gamma": self.gamma}
        if self.printer is not None:
            d["printer"] = self.printer.name
        if self.at is not None:
            d["at"] = list(self.at)
        return d


@dataclass(frozen=True)
class Placement:
    """Where a traced model lands on a printer's plate, in sub-pixel units.

    The model's (sub-)pixel ``(row j, column i)`` and layer ``k`` of the
    traced grid become plate sub-pixel ``(j + dj, i + di)`` and plate layer
    ``k - k_first``. With ``aa = n``, plate sub-pixel ``(J, I)`` lies in
    output pixel ``(J // n, I // n)``, and its centre is at
    ``X = (I + 1/2) px / n``, ``Y = display_y - (J + 1/2) py / n``: the n x n
    sub-pixel centres sit symmetrically inside each printer pixel.

    Attributes
    ----------
    printer : Printer
    aa : int
    di, dj : int
        Sub-pixel offsets from the traced grid to the plate.
    k_first : int
        Traced layer that becomes plate layer 0 (the lowest with an inside
        voxel centre).
    layers : int
        Plate layers written.
    layer_height : float, mm
    footprint : (4,) float, plate mm
        ``X0, Y0, X1, Y1`` of the model's inside pixels on the plate.
    """

    printer: Printer
    aa: int
    di: int
    dj: int
    k_first: int
    layers: int
    layer_height: float
    footprint: tuple[float, float, float, float]

    @property
    def grid(self):
        """The plate grid (full printer resolution), a SliceGrid."""
        px, py = self.printer.pixel_size
        nx, ny = self.printer.pixels
        origin = (0.5 * px, self.printer.display[1] - 0.5 * py, 0.5 * self.layer_height)
        return SliceGrid(origin, (px, py), self.layer_height, nx, ny, self.layers)

    def offset(self, grid) -> tuple[float, float, float]:
        """Translation (mm) from scene to plate coordinates.

        Parameters
        ----------
        grid : slicer.tracer.grid.SliceGrid
            The traced grid this placement was made for.

        Returns
        -------
        dx, dy, dz : float, mm
            A scene point ``(x, y, z)`` lands on the plate at
            ``(x + dx, y + dy, z + dz)``: the centre of traced sub-pixel
            ``(j, i)`` goes to the centre of plate sub-pixel
            ``(j + dj, i + di)``, and the centre of traced layer ``k_first``
            to the centre of plate layer 0 (``z = h / 2``).
        """
        spx, spy = grid.pixel_size
        x0, y0, z0 = grid.origin
        h = self.layer_height
        return ((self.di + 0.5) * spx - x0,
                self.printer.display[1] - (self.dj + 0.5) * spy - y0,
                0.5 * h - (z0 + self.k_first * h))


def place(result, printer: Printer, aa: int = 1, at=None) -> Placement:
    """Place a traced model on ``printer``'s plate.

    Parameters
    ----------
    result : slicer.tracer.slicing.SliceResult or slicer.scale.tiles.StreamedResult
        Traced with pixel pitch ``printer.pixel_size / aa`` (any origin).
    printer : Printer
    aa : int
        Supersampling factor the result was traced with.
    at : (2,) float, optional, plate mm
        Target of the centre of the model's footprint (default: plate
        centre). The model moves by whole sub-pixels, so it lands within
        half a sub-pixel of the target.

    Raises
    ------
    GridError
        The model does not fit on the plate (naming both sizes), is taller
        than the printer, or has no inside voxel.
    """
    g = result.grid
    box = result.inside_box() if result.n_runs else None
    if box is None:
        raise GridError("the surface is empty: nothing to place on the plate")
    spx, spy = g.pixel_size
    ppx, ppy = printer.pixel_size
    if not (math.isclose(spx * aa, ppx, rel_tol=1e-9) and math.isclose(spy * aa, ppy, rel_tol=1e-9)):
        raise GridError(f"{printer.name}: traced pitch {spx:g} x {spy:g} mm does not match the printer's "
                        f"{ppx:g} x {ppy:g} mm / {aa}")
    i0, i1, j0, j1, k_first, k_last = box
    W, H = printer.display
    size_x, size_y = (i1 - i0 + 1) * spx, (j1 - j0 + 1) * spy
    height = (k_last - k_first + 1) * g.layer_height
    tx, ty = (0.5 * W, 0.5 * H) if at is None else (float(at[0]), float(at[1]))
    di = int(round(tx / spx - 0.5 - 0.5 * (i0 + i1)))
    dj = int(round((H - ty) / spy - 0.5 - 0.5 * (j0 + j1)))
    nI, nJ = printer.pixels[0] * aa, printer.pixels[1] * aa
    X0, X1 = (i0 + di) * spx, (i1 + di + 1) * spx
    Y1, Y0 = H - (j0 + dj) * spy, H - (j1 + dj + 1) * spy
    where = "" if at is None else f" at X {tx:g} Y {ty:g}"
    if size_x > W + 1e-9 or size_y > H + 1e-9:
        raise GridError(f"the model ({size_x:.2f} x {size_y:.2f} mm) does not fit on the {printer.label} "
                        f"plate ({W:g} x {H:g} mm)")
    if i0 + di < 0 or i1 + di >= nI or j0 + dj < 0 or j1 + dj >= nJ:
        raise GridError(f"the model ({size_x:.2f} x {size_y:.2f} mm) placed{where} would cover "
                        f"X {X0:.2f}..{X1:.2f}, Y {Y0:.2f}..{Y1:.2f} mm, outside the {printer.label} plate "
                        f"(X 0..{W:g}, Y 0..{H:g} mm)")
    if height > printer.max_height + 1e-9:
        raise GridError(f"the model is {height:.2f} mm tall; the {printer.label} prints at most "
                        f"{printer.max_height:g} mm")
    return Placement(printer, aa, di, dj, k_first, k_last - k_first + 1, g.layer_height, (X0, Y0, X1, Y1))




def plate_printer(fmt: str, path, grid, settings) -> Printer:
    """The printer of a printer-format writer, checking the layers fill its plate.

    Raises
    ------
    OutputError
        No printer in ``settings``, or ``grid`` is not the printer's display.
    """
    if settings is None or settings.printer is None:
        raise OutputError(f"{path}: the {fmt} format needs a printer profile (--printer)")
    p = settings.printer
    if (grid.width, grid.height) != tuple(p.pixels):
        raise OutputError(f"{path}: the layers are {grid.width} x {grid.height} px, the {p.label} display is "
                          f"{p.pixels[0]} x {p.pixels[1]} px")
    return p


__all__ = ["Printer", "PRINTERS", "get_printer", "PrintSettings", "Placement", "place", "plate_printer"]
