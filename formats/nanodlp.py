"""NanoDLP archives (``.nanodlp``): JSON manifests plus one PNG per layer.

A zip (docs.nanodlp.com/manual/format; docs/formats.md §2.2) holding:

* ``1.png`` ... ``N.png``: the layers, 1-based, no zero padding. NanoDLP's
  mono-LCD convention (UVtools' "NanoDLP (Mono)", mslicer/``msla_format``):
  an 8-bit **RGB** PNG in which every byte is one display pixel, so a row
  of ``PWidth`` pixels is a PNG row of ``PWidth / 3`` RGB pixels (R, G, B =
  display columns 3i, 3i+1, 3i+2). The display width must therefore be a
  multiple of 3: without ``--printer`` the grid is padded on the right
  (+x side) with up to two empty columns (``PWidth`` is the padded width);
  every built-in printer's native width is already a multiple of 3.
* ``meta.json``: format version 2, program, version; ``"Profile": false``,
  so NanoDLP keeps the machine's own resin profile (lift, G-code); the
  exposure values below are recorded for readers such as UVtools.
* ``info.json``: per layer ``TotalSolidArea``, ``LargestArea``,
  ``SmallestArea`` (mm²; pixels > 0, islands 8-connected), the bounding box
  ``MinX``/``MinY`` (first column/row) and ``MaxX``/``MaxY`` (one past the
  last), in display pixels, and ``AreaCount`` (islands).
* ``plate.json``: layer count, resin volume (``TotalSolidArea``, ml = the
  grey-weighted voxel volume), the bounding box in mm about the display
  centre (x right, y down the image, z from 0 to the stack height).
* ``profile.json``: layer height (``Depth``, µm), exposure (``CureTime``)
  and bottom exposure (``SupportCureTime``), s, bottom layers.
* ``options.json`` and the same document as ``slicer.json`` (NanoDLP reads
  the first, UVtools the second): display size ``PWidth`` x ``PHeight``,
  pixel pitch (``XPixelSize``, mm; ``XRes``, µm), ``Thickness`` (µm).
* ``3d.png``: a 200 x 100 RGBA top view (the size the NanoDLP docs give).

Number types follow the readers' contract (``msla_format``'s serde
structs): lengths, areas and times are JSON floats (``50.0``), counts and
flags integers; a µm field that the contract types as an integer is written
only when the value is a whole number of µm.

With ``--printer`` the layers are the printer's native images
(:meth:`Printer.to_native`, as SL1 and GOO store them) and ``ImageMirror``
records the profile's ``mirror_x``; without it they are the grid's images
(columns +x, rows -y) and ``ImageMirror`` is 0.

Layers stream into a temporary zip beside the target (PNG members stored,
JSON deflated, fixed timestamps); the manifests and the preview are added at
the end, then the file is renamed over the target.
"""
from __future__ import annotations

import json

import numpy as np

from slicer._kernels.formats.islands import island_sizes as _island_sizes
from slicer.errors import OutputError

from formats.base import build_time, png_bytes_sparse
from formats.estimate import LayerMeter
from formats.printer_profiles import PrintSettings
from formats.rle import occupied
from formats.thumbnails import TopView, png_rgba
from formats.zip_stack import ZipArchiveWriter

#: NanoDLP meta.json format version
FORMAT_VERSION = 2
#: size of the ``3d.png`` preview (w, h), as the NanoDLP docs describe it
PREVIEW = (200, 100)


def island_sizes(image: np.ndarray) -> np.ndarray:
    """Pixel counts of the 8-connected islands of a layer's non-zero pixels.

    Parameters
    ----------
    image : (h, w) uint8

    Returns
    -------
    (n,) int64
        One count per island, in the row-major order of their first pixel.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise OutputError(f"island_sizes: expected a 2-D image, got shape {img.shape}")
    return _island_sizes(np.ascontiguousarray(img != 0, dtype=np.uint8))


def layer_info(image: np.ndarray, pitch: tuple[float, float], box=False) -> dict:
    """The ``info.json`` entry of one stored layer.

    Parameters
    ----------
    image : (h, w) uint8
        The layer as stored (display pixels).
    pitch : (2,) float, mm
        Pixel pitch along the image's columns and rows.
    box : (r0, r1, c0, c1), None or False
        Where the non-zero pixels are, if known (:func:`formats.rle.occupied`):
        only that box is read. None: the layer is empty. False: read it all.

    Returns
    -------
    dict
        ``TotalSolidArea``, ``LargestArea``, ``SmallestArea`` (mm², floats),
        ``MinX``, ``MinY``, ``MaxX``, ``MaxY`` (pixels, max exclusive) and
        ``AreaCount``; zeros for an empty layer.
    """
    R0, C0 = 0, 0
    if box is None:
        image = image[:0, :0]
    elif box is not False:
        R0, R1, C0, C1 = box
        image = image[R0:R1, C0:C1]
    rows = np.flatnonzero(image.any(axis=1))
    if rows.size == 0:
        return {"TotalSolidArea": 0.0, "LargestArea": 0.0, "SmallestArea": 0.0,
                "MinX": 0, "MinY": 0, "MaxX": 0, "MaxY": 0, "AreaCount": 0}
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    band = image[r0:r1]
    cols = np.flatnonzero(band.any(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    sizes = island_sizes(band[:, c0:c1])
    a = float(pitch[0]) * float(pitch[1])
    return {"TotalSolidArea": float(sizes.sum()) * a, "LargestArea": float(sizes.max()) * a,
            "SmallestArea": float(sizes.min()) * a, "MinX": C0 + c0, "MinY": R0 + r0, "MaxX": C0 + c1,
            "MaxY": R0 + r1, "AreaCount": int(sizes.size)}


def pack_rgb(image: np.ndarray) -> np.ndarray:
    """A (h, w) display image as NanoDLP's mono-LCD PNG pixels.

    Parameters
    ----------
    image : (h, w) uint8, w a multiple of 3

    Returns
    -------
    (h, w / 3, 3) uint8
        RGB pixel i of a row holds display columns 3i, 3i+1, 3i+2.
    """
    h, w = image.shape
    if w % 3:
        raise OutputError(f"pack_rgb: the width {w} is not a multiple of 3")
    return np.ascontiguousarray(image, dtype=np.uint8).reshape(h, w // 3, 3)


def unpack_rgb(pixels: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_rgb`: (h, w, 3) RGB to the (h, 3 w) display image."""
    h, w, c = pixels.shape
    if c != 3:
        raise OutputError(f"unpack_rgb: expected 3 channels, got {c}")
    return np.ascontiguousarray(pixels, dtype=np.uint8).reshape(h, 3 * w)


def _whole_um(mm: float) -> int | None:
    """``mm`` in µm as an int when it is a whole number of µm, else None."""
    um = mm * 1000.0
    r = round(um)
    return int(r) if abs(um - r) <= 1e-9 * max(1.0, abs(um)) else None


def _json(doc) -> str:
    return json.dumps(doc, indent=2) + "\n"


class NanoDlpWriter(ZipArchiveWriter):
    """NanoDLP zip (``.nanodlp``), with or without a printer profile."""

    name = "nanodlp"

    def __init__(self, path, grid, meta=None, force=False, settings=None):
        if settings is None:
            settings = PrintSettings(None, grid.layer_height)
        p = settings.printer
        if p is not None and (grid.width, grid.height) != tuple(p.pixels):
            raise OutputError(f"{path}: the layers are {grid.width} x {grid.height} px, the {p.label} display is "
                              f"{p.pixels[0]} x {p.pixels[1]} px")
        if p is not None:
            rows, cols = p.native_shape
            px, py = p.pixel_size
            self.pitch = (py, px) if p.orientation == "portrait" else (px, py)   # along columns, rows
            if cols % 3:
                raise OutputError(f"{path}: NanoDLP stores 3 display pixels per PNG pixel; the {p.label} "
                                  f"display is {cols} px wide, not a multiple of 3")
        else:
            rows, cols = grid.height, -(-grid.width // 3) * 3
            self.pitch = tuple(grid.pixel_size)
        super().__init__(path, grid, meta, force, settings)
        self.printer = p
        self.display = (cols, rows)                  # PWidth, PHeight
        self._top = TopView((grid.height, grid.width))
        self._info: list[dict] = []
        self._meter = LayerMeter()

    def _display_view(self, image: np.ndarray, box):
        """The layer as the display shows it, and where its pixels are there:
        the printer's native view and box, or the grid's image itself (the
        padding columns on the right of the display are zero)."""
        if self.printer is not None:
            return self.printer.to_native(image), self.printer.native_box(box)
        if image.shape != (self.grid.height, self.grid.width):
            raise OutputError(f"layer image must be {(self.grid.height, self.grid.width)}, got {image.shape}")
        return image, box

    parallel_encode = True

    def encode_layer(self, k: int, image: np.ndarray):
        """(PNG bytes of the packed display image, the layer's info record, the
        image's :func:`formats.rle.occupied` box).

        Only the box of the display image that holds the model is read
        (a transposed or mirrored view of the plate is not gathered whole);
        the zero rows around it are not deflated again
        (:func:`formats.base.png_bytes_sparse`).
        """
        box = occupied(image)
        view, vbox = self._display_view(np.asarray(image, dtype=np.uint8), box)
        return self._packed_png(view, vbox), layer_info(view, self.pitch, box=vbox), box

    def _packed_png(self, view: np.ndarray, box) -> bytes:
        """PNG of the display image (:func:`pack_rgb`: 3 display pixels per RGB
        pixel) from the box of ``view`` that holds its non-zero pixels."""
        cols, rows = self.display
        if box is None:
            return png_bytes_sparse(rows, cols // 3, np.zeros((0, 0, 3), np.uint8), (0, 0))
        r0, r1, c0, c1 = box
        p0, p1 = c0 // 3, -(-c1 // 3)        # the RGB pixels holding display columns c0..c1-1
        block = np.zeros((r1 - r0, 3 * (p1 - p0)), np.uint8)
        block[:, c0 - 3 * p0:c1 - 3 * p0] = view[r0:r1, c0:c1]
        return png_bytes_sparse(rows, cols // 3, pack_rgb(block), (r0, p0))

    def write_layer(self, k: int, image: np.ndarray) -> None:
        self.store_layer(k, image, self.encode_layer(k, image))

    def store_layer(self, k: int, image: np.ndarray, payload) -> None:
        self.next_layer(k)
        data, info, box = payload
        self.add(f"{k + 1}.png", data, False)
        self._info.append(info)
        self._meter.add(image, box)
        self._top.add(k, image, box)
        self._k += 1

    # ---------------------------------------------------------------- manifests
    def bounds(self) -> dict:
        """Bounding box of every layer's pixels, mm: x right and y down the
        display image from its centre, z from 0 to the stack height."""
        cols, rows = self.display
        cw, rh = self.pitch
        solid = [i for i in self._info if i["AreaCount"]]
        h = self.settings.layer_height
        b = {"XMin": 0.0, "XMax": 0.0, "YMin": 0.0, "YMax": 0.0, "ZMin": 0.0, "ZMax": float(self._k * h)}
        if solid:
            b["XMin"] = (min(i["MinX"] for i in solid) - cols / 2) * cw
            b["XMax"] = (max(i["MaxX"] for i in solid) - cols / 2) * cw
            b["YMin"] = (min(i["MinY"] for i in solid) - rows / 2) * rh
            b["YMax"] = (max(i["MaxY"] for i in solid) - rows / 2) * rh
        return {k: float(v) for k, v in b.items()}

    def meta_json(self) -> dict:
        gen = self.meta.get("generator", "skelslice")
        return {"FormatVersion": FORMAT_VERSION, "Distro": "generic", "Program": "skelslice",
                "Version": gen.split()[-1], "OS": "any", "Arch": "any", "Profile": False}

    def plate_json(self) -> dict:
        est = self.print_estimate()                  # also without a printer: PrintEst = the exposures
        t = int(build_time().timestamp())
        return {"PlateID": 0, "ProfileID": 0, "CreatedDate": t, "Updated": t, "Path": self.path.stem,
                "LayersCount": self._k, "Processed": True, "TotalSolidArea": float(est.volume_ml),
                "PrintEst": int(round(est.seconds)), **self.bounds()}

    def print_estimate(self):
        """:mod:`formats.estimate` of the layers written: exposures, plus the
        printer's lift and waits with ``--printer`` (NanoDLP's own profile
        drives the machine; ``PrintEst`` is the estimate with ours)."""
        px, py = self.grid.pixel_size
        return self._meter.estimate(self.settings, pixel_area=float(px) * float(py))

    def profile_json(self) -> dict:
        s, p = self.settings, self.printer
        um = s.layer_height * 1000.0
        desc = self.meta.get("generator", "skelslice")
        if self.meta.get("scene"):
            desc += f": {self.meta['scene']}"
        doc = {"Title": p.label if p is not None else "skelslice", "Desc": desc,
               "Depth": float(um), "SupportDepth": float(um),
               "CureTime": float(s.exposure), "SupportCureTime": float(s.bottom_exposure),
               "SupportLayerNumber": int(s.bottom_layers), "TransitionalLayer": 0,
               "AntiAlias": int(s.aa), "FillColor": "#ffffff", "BlankColor": "#000000", "IgnoreMask": 1,
               "Updated": int(build_time().timestamp())}
        return doc

    def options_json(self) -> dict:
        s, p = self.settings, self.printer
        cols, rows = self.display
        cw, rh = self.pitch
        b = self.bounds()
        doc = {"Type": "png", "PWidth": cols, "PHeight": rows, "Thickness": float(s.layer_height * 1000.0)}
        depth = _whole_um(s.layer_height)
        if depth is not None:
            doc["SupportDepth"] = depth
        doc.update({
            "SupportLayerNumber": int(s.bottom_layers),
            "XOffset": cols // 2, "YOffset": rows // 2,
            "XPixelSize": float(cw), "YPixelSize": float(rh),
            "Boundary": b,
            "FillColor": "#ffffff", "BlankColor": "#000000",
            "AntiAlias": int(s.aa), "ImageRotate": 0, "IgnoreMask": 1,
            "XRes": float(cw * 1000.0), "YRes": float(rh * 1000.0),
            "PreviewWidth": PREVIEW[0], "PreviewHeight": PREVIEW[1],
            "ImageMirror": int(bool(p is not None and p.mirror_x)),
            "DisplayController": 1,
            "LayerCount": self._k,
            "FillColorRGB": {"R": 255, "G": 255, "B": 255, "A": 255},
            "BlankColorRGB": {"R": 0, "G": 0, "B": 0, "A": 255},
        })
        return doc

    def final_members(self):
        self.estimate = self.print_estimate() if self.printer is not None else None
        options = _json(self.options_json())
        yield "meta.json", _json(self.meta_json()), True
        yield "info.json", _json(self._info), True
        yield "plate.json", _json(self.plate_json()), True
        yield "profile.json", _json(self.profile_json()), True
        yield "options.json", options, True
        yield "slicer.json", options, True
        yield "3d.png", png_rgba(self._top.render(PREVIEW)), False


__all__ = ["NanoDlpWriter", "layer_info", "island_sizes", "pack_rgb", "unpack_rgb"]
