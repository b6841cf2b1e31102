"""A layer viewer in one self-contained HTML file.

:class:`PreviewBuilder` takes the layers of a :class:`~slicer.printability.LayerStack`
one at a time (it is the ``on_layer`` callback of the check's pass, so the
layers are read once), and :meth:`PreviewBuilder.html` writes a page built
from ``preview_template.html`` (shipped as package data): inline CSS and
JavaScript, no network (a Content-Security-Policy forbids it), opens from
disk.

What the file holds
-------------------
* each layer cut to the box of its non-zero pixels, as a PNG (1-bit when the
  layer is only 0 and 255, else 8-bit grey) in base64, with the box's
  corner; empty layers as ``null``. The browser decodes a layer only when
  it is shown (and its neighbours, for stepping), keeping a few dozen
  decoded, so opening a job of thousands of layers costs one JSON parse of
  the strings;
* the check's findings (islands, thin struts, traps, area jumps) with their
  layer and pixel position, the per-layer cured area, the contours (rings
  in pixel coordinates, simplified to a fifth of a pixel, as differences of
  integers in 1/16 pixel), renders of the
  part (the scene's transparent render when the scene is known, and X-ray
  projections of the layers), and the grid.

The layer canvas holds the layer at its own resolution (one canvas pixel per
layer pixel, grey = the stored value); zoom and pan scale it on screen
without resampling its pixels, and the contours and markers are drawn on a
second canvas above it.
"""
from __future__ import annotations

import base64
import io
import json
from importlib import resources
from pathlib import Path

import numpy as np
import shapely
from PIL import Image

from slicer.atomic import write_bytes
from slicer.errors import ReadError
from slicer.printability.report import CheckReport, mm_text
from slicer.printability.stream import SOLID, LayerStack

#: findings written into the page (the rest are counted)
MAX_FINDINGS = 2000
#: contour simplification, pixels
CONTOUR_SIMPLIFY = 0.2
#: contour coordinates are stored in 1/CONTOUR_QUANTUM pixel
CONTOUR_QUANTUM = 16
#: longest side of the X-ray projections, pixels
XRAY_SIDE = 360
#: opacity of one solid voxel in the X-ray projections
XRAY_OPACITY = 0.06


def layer_png(image: np.ndarray) -> tuple[int, int, int, int, str] | None:
    """A layer cut to its non-zero pixels: ``(column, row, width, height, base64 PNG)``, or None if empty.

    The PNG is 1-bit when every pixel is 0 or 255, else 8-bit grey; either
    decodes to the same grey values.
    """
    rows = np.flatnonzero(image.any(axis=1))
    if rows.size == 0:
        return None
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    band = image[r0:r1]
    cols = np.flatnonzero(band.any(axis=0))
    c0, c1 = int(cols[0]), int(cols[-1]) + 1
    crop = np.ascontiguousarray(band[:, c0:c1])
    binary = not np.any((crop != 0) & (crop != 255))
    im = Image.fromarray(crop, "L")
    if binary:
        im = im.convert("1", dither=Image.Dither.NONE)
    buf = io.BytesIO()
    im.save(buf, format="PNG", optimize=True)
    return c0, r0, c1 - c0, r1 - r0, base64.b64encode(buf.getvalue()).decode("ascii")


class PreviewBuilder:
    """Collects what the page shows while the layers stream past.

    Parameters
    ----------
    stack : LayerStack
        Only its grid and placement are used here; feed the layers with :meth:`add`.
    """

    def __init__(self, stack: LayerStack):
        self.stack = stack
        g = stack.grid
        self.layers: list = []
        self.areas: list[float] = []
        self._front: list[np.ndarray] = []       # per layer: solid pixels per column (seen from -Y)
        self._side: list[np.ndarray] = []        # per layer: solid pixels per row (seen from +X)
        self._pixel_area = g.pixel_size[0] * g.pixel_size[1]

    def add(self, k: int, image: np.ndarray) -> None:
        """Layer ``k`` (in order), a (height, width) uint8 image."""
        if k != len(self.layers):
            raise ValueError(f"layers must come in order: expected {len(self.layers)}, got {k}")
        img = np.asarray(image, dtype=np.uint8)
        self.layers.append(layer_png(img))
        solid = img >= SOLID
        self.areas.append(float(np.count_nonzero(solid)) * self._pixel_area)
        self._front.append(solid.sum(axis=0, dtype=np.int32))
        self._side.append(solid.sum(axis=1, dtype=np.int32))

    # ------------------------------------------------------------------ renders
    def xray(self) -> list[dict]:
        """X-ray projections of the layers (front: along -Y... seen from the front; side: seen from +X)."""
        g = self.stack.grid
        if not self.layers:
            return []
        out = []
        for name, counts, across in (("front (X-Z), X-ray of the layers", self._front, g.pixel_size[0]),
                                     ("side (Y-Z), X-ray of the layers", self._side, g.pixel_size[1])):
            c = np.asarray(counts, dtype=np.float64)[::-1]            # top layer first
            if name.startswith("side"):
                c = c[:, ::-1]                                        # +Y to the right, seen from +X
            out.append({"caption": name, "src": _data_uri(_xray_png(c, across, g.layer_height))})
        return out

    # ------------------------------------------------------------------ page
    def page(self, title: str, report: CheckReport | None = None, contours: dict | None = None,
             renders: list[dict] | None = None, job: str = "") -> bytes:
        """The HTML page (UTF-8 bytes)."""
        g, st = self.stack.grid, self.stack
        findings = _findings(report, st) if report is not None else []
        left = max(0, len(findings) - MAX_FINDINGS)
        findings = findings[:MAX_FINDINGS]
        start = min((f["layer"] for f in findings if 0 <= f["layer"] < len(self.layers)), default=None)
        if start is None:
            solid = [k for k, a in enumerate(self.areas) if a > 0]
            start = solid[len(solid) // 2] if solid else 0
        frame_label = {"plate": "plate mm (build plate at Z = 0)", "scene": "scene mm",
                       "display": "display mm (about its centre)"}.get(st.frame, st.frame)
        data = {
            "title": title, "width": g.width, "height": g.height, "grid": {**g.to_dict(), "layers": len(self.layers)},
            "frame": st.frame, "frame_label": frame_label, "window": list(st.window), "full_shape": list(st.full_shape),
            "plate": st.frame == "plate", "layers": [list(v) if v else None for v in self.layers],
            "areas": [round(a, 6) for a in self.areas], "findings": findings, "findings_left": left,
            "check": None if report is None else {"ok": report.ok, "blocking": report.blocking},
            "contours": _contours_px(contours, st) if contours else None, "contour_quantum": CONTOUR_QUANTUM,
            "renders": list(renders or []) + self.xray(), "job": job, "start": int(start),
        }
        text = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
        tpl = resources.files("slicer.viewer").joinpath("preview_template.html").read_text("utf-8")
        html = tpl.replace("__TITLE__", _escape(title)).replace("__DATA__", text)
        return html.encode("utf-8")

    def write(self, path, force: bool = False, **page) -> int:
        """Write the page atomically; returns its size in bytes."""
        data = self.page(**page)
        write_bytes(path, data, force)
        return len(data)


def _escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def png_data_uri(rgba: np.ndarray) -> str:
    """A data URI of an (h, w, 3|4) uint8 image as PNG."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba)).save(buf, format="PNG", optimize=True)
    return _data_uri(buf.getvalue())


def _xray_png(counts: np.ndarray, across: float, layer_height: float) -> bytes:
    """A projection of solid counts as light through a semi-transparent part
    (white background, orange material), scaled to physical proportions."""
    t = (1.0 - XRAY_OPACITY) ** counts
    colour = np.array([240.0, 124.0, 30.0])
    rgb = 255.0 * t[..., None] + colour * (1.0 - t[..., None])
    img = Image.fromarray(np.clip(np.rint(rgb), 0, 255).astype(np.uint8), "RGB")
    hmm, wmm = counts.shape[0] * layer_height, counts.shape[1] * across
    scale = XRAY_SIDE / max(hmm, wmm)
    size = (max(1, int(round(wmm * scale))), max(1, int(round(hmm * scale))))
    img = img.resize(size, Image.Resampling.BILINEAR)
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _px(st: LayerStack, x: float, y: float) -> tuple[float, float]:
    c, r = st.pixel_of(x, y)
    return round(float(c), 2), round(float(r), 2)


def _findings(report: CheckReport, st: LayerStack) -> list[dict]:
    """The report's findings as markers: kind, layer, pixel position, label and text."""
    g = st.grid
    px, py = g.pixel_size
    out = []
    for i in report.islands:
        c, r = _px(st, i.x, i.y)
        out.append({"kind": "island", "layer": i.layer, "col": c, "row": r, "box": list(i.bbox),
                    "label": f"island {i.area:.3g} mm²",
                    "text": f"layer {i.layer}: {i.area:.4g} mm² at x {mm_text(i.x)} y {mm_text(i.y)} mm, "
                            "held by nothing below"})
    for t in report.thin_segments or []:
        c, r = _px(st, t.x, t.y)
        out.append({"kind": "thin", "layer": t.layer, "col": c, "row": r, "radius": t.radius_width / px,
                    "label": f"segment {t.segment}: {t.width:.3g} mm",
                    "text": f"segment {t.segment}: printed {t.width:.4g} mm < {t.threshold:.4g} mm (layer {t.layer})"})
    for t in report.traps:
        c, r = _px(st, t.x, t.y)
        what = "closed cavity" if t.kind == "closed" else "suction cup"
        out.append({"kind": "trap", "layer": t.layers[0], "layers": list(t.layers), "col": c, "row": r,
                    "box": [t.bbox[0], t.bbox[1], t.bbox[3], t.bbox[4]], "label": f"{what} {t.volume:.3g} mm³",
                    "text": f"{what}, {t.volume:.4g} mm³, layers {t.layers[0]}-{t.layers[1]}"})
    for j in report.areas.get("over", []):
        out.append({"kind": "jump", "layer": j["layer"], "col": g.width / 2, "row": g.height / 2,
                    "label": f"+{j['jump']:.3g} mm²",
                    "text": f"layer {j['layer']}: area {j['from']:.4g} -> {j['to']:.4g} mm²"})
    out.sort(key=lambda f: (f["layer"], f["kind"]))
    return out


def _contours_px(contours: dict, st: LayerStack) -> dict:
    """Layer -> rings in pixel coordinates, simplified to :data:`CONTOUR_SIMPLIFY`
    pixels and stored compactly: integers in 1/:data:`CONTOUR_QUANTUM` pixel, the
    first point then the differences, ``[c0, r0, dc1, dr1, ...]``."""
    g = st.grid
    px, py = g.pixel_size
    x0, y0 = g.origin[0], g.origin[1]
    out = {}
    for k, rings in contours.items():
        flat = []
        for ring in rings:
            xy = np.asarray(ring, dtype=np.float64)[:, :2]
            if xy.shape[0] < 3:
                continue
            cr = np.stack([(xy[:, 0] - x0) / px, (y0 - xy[:, 1]) / py], axis=1)
            simple = shapely.simplify(shapely.LinearRing(cr), CONTOUR_SIMPLIFY)
            pts = np.asarray(simple.coords)[:-1] if not simple.is_empty else cr
            if pts.shape[0] < 3:
                pts = cr
            q = np.rint(pts * CONTOUR_QUANTUM).astype(np.int64)
            q[1:] -= q[:-1].copy()
            flat.append(q.ravel().tolist())
        if flat:
            out[str(int(k))] = flat
    return out


def decode_ring(ints) -> np.ndarray:
    """The (n, 2) pixel coordinates (column, row) of one stored ring (inverse of the page's encoding)."""
    q = np.asarray(ints, dtype=np.int64).reshape(-1, 2)
    return np.cumsum(q, axis=0) / CONTOUR_QUANTUM


def contours_of_polygons(items) -> dict:
    """Layer -> list of rings (mm) from ``(k, z, MultiPolygon)`` items (:func:`slicer.contours.iter_contours`)."""
    out = {}
    for k, _z, mp in items:
        rings = []
        for poly in getattr(mp, "geoms", []):
            rings.append(np.asarray(poly.exterior.coords)[:-1, :2])
            rings.extend(np.asarray(r.coords)[:-1, :2] for r in poly.interiors)
        if rings:
            out[int(k)] = rings
    return out


def read_contours(path) -> dict:
    """Layer -> rings (mm) of a contours file written by ``slice --contours`` (``.geojson`` or ``.json``).

    Raises
    ------
    slicer.errors.ReadError
        Not such a file (naming the problem).
    """
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise ReadError(f"{p}: cannot read the contours ({exc})") from None
    out = {}
    try:
        if doc.get("type") == "FeatureCollection":
            for f in doc["features"]:
                k = int(f["properties"]["layer"])
                out[k] = [np.asarray(r, dtype=np.float64)[:-1] for poly in f["geometry"]["coordinates"] for r in poly]
        else:
            for item in doc["layers"]:
                out[int(item["layer"])] = [np.asarray(r, dtype=np.float64) for poly in item["polygons"] for r in poly]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ReadError(f"{p}: not a skelslice contours file ({type(exc).__name__}: {exc})") from None
    return out


__all__ = ["PreviewBuilder", "layer_png", "png_data_uri", "contours_of_polygons", "read_contours", "decode_ring",
           "MAX_FINDINGS", "CONTOUR_QUANTUM"]
