"""Common Layer Interface (CLI v2.0): binary (long or short form) and ASCII.

CLI is the contour exchange format of powder-bed and SLA machine software
(spec: hmilch.net/downloads/cli_format.html). A file is an ASCII header
followed by a geometry section of layers, each holding closed polylines.

What skelslice writes
---------------------
Header (always ASCII, one command per line)::

    $$HEADERSTART
    $$BINARY                      ($$ASCII for the ASCII form)
    $$UNITS/0.001                 mm per coordinate unit
    $$VERSION/200
    $$LABEL/1,skelslice
    $$DIMENSION/0.000000,0.000000,0.000000,W,D,H   (mm)
    $$LAYERS/N
    // skelslice origin: X0,Y0,Z0 (scene mm of CLI point 0,0,0) //
    $$HEADEREND

* **Coordinates are relative to the job's box** (the grid's voxel faces,
  :meth:`ContourWriter.box`): CLI ``(0, 0, 0)`` is the scene point
  ``(x0, y0, z0)`` given in the ``origin`` comment. Build-platform software
  expects non-negative coordinates with the first layer starting at z = 0
  (the short form cannot store anything else), so all forms use the same
  placement. Scene mm = CLI value x units + origin.
* ``$$LAYER/z`` is the **upper surface** of the layer: layer k (0-based) has
  z = (k + 1) x layer height; the thickness is the difference to the previous
  layer, as the spec defines it. Every layer is written, empty ones too.
* One ``POLYLINE`` per ring, closed (the first point repeated last), with
  the spec's direction flag: **1 = counter-clockwise, outer boundary; 0 =
  clockwise, hole**, seen from above (looking in -z). No hatches.
* Forms (``form=``): ``"long"`` (binary commands 127/130: f32 z and
  coordinates, i32 id/dir/n; the default, registry name ``cli``),
  ``"short"`` (binary 128/129: u16 everything, so coordinates are integers in
  [0, 65535] units; default units 0.005 mm, i.e. a 327 mm range; registry
  name ``cli-short``), ``"ascii"`` (``$$GEOMETRYSTART`` ... ``$$GEOMETRYEND``
  text, coordinates with 3 decimals in units; registry name ``cli-ascii``).
  Binary data is little-endian and starts right after the ``D`` of
  ``$$HEADEREND`` (no newline), unaligned (no ``$$ALIGN``).
* Quantisation (f32, integers or 3 decimals) can merge neighbouring points:
  repeated points are dropped, and a ring left with fewer than 3 distinct
  points or whose orientation flips is dropped (with its holes, for an outer
  ring); :attr:`CliWriter.dropped_rings` counts them. With the default units
  this happens only for features far below the pixel size.
* No ``$$DATE``, so the same job gives byte-identical files.

:func:`read_cli` reads all three forms back (used by the tests to check the
ASCII form against the binary one; the binary form is also checked by the
independent ``colain`` crate, see ``tests/readers``).
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely

from slicer.errors import OptionError, OutputError, ReadError

from formats.contour_base import ContourWriter, rings

#: binary command ids (CLI v2.0)
CMD_LAYER_LONG, CMD_LAYER_SHORT = 127, 128
CMD_POLYLINE_SHORT, CMD_POLYLINE_LONG = 129, 130
CMD_HATCHES_SHORT, CMD_HATCHES_LONG = 131, 132
#: polyline direction flags
DIR_HOLE, DIR_OUTER, DIR_OPEN = 0, 1, 2
#: default mm per coordinate unit, per form
DEFAULT_UNITS = {"long": 0.001, "ascii": 0.001, "short": 0.005}
_ORIGIN_RE = re.compile(r"skelslice origin:\s*([^,\s]+),([^,\s]+),([^,\s/]+)")


def _num(x: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(x))


class CliWriter(ContourWriter):
    """Common Layer Interface writer (see the module docstring for the layout).

    Parameters
    ----------
    path, grid, meta, force
        As :class:`~formats.contour_base.ContourWriter`.
    form : {"long", "short", "ascii"}
        Binary long (f32), binary short (u16) or ASCII geometry.
    units : float, optional
        mm per coordinate unit (default 0.001 for long and ASCII, 0.005 for short).
    """

    name = "cli"
    suffix = ".cli"

    def __init__(self, path, grid, meta=None, force=False, form: str = "long", units: float | None = None):
        if form not in DEFAULT_UNITS:
            raise OptionError(f"CLI form must be one of {sorted(DEFAULT_UNITS)}, got {form!r}")
        self.form = form
        self.units = float(units if units is not None else DEFAULT_UNITS[form])
        if not (np.isfinite(self.units) and self.units > 0):
            raise OptionError(f"CLI units must be a finite number > 0 (mm per unit), got {units!r}")
        self.dropped_rings = 0
        self._last_z_units = None
        super().__init__(path, grid, meta, force)
        x0, y0, z0, x1, y1, z1 = self.box()
        self._origin = np.array([x0, y0, z0])
        self._size = (x1 - x0, y1 - y0, z1 - z0)

    # ------------------------------------------------------------------ hooks
    def _begin(self) -> None:
        w, d, h = self._size
        label = "skelslice"
        if self.meta.get("scene"):
            label += " " + Path(str(self.meta["scene"])).name.replace(",", "_")
        lines = [
            "$$HEADERSTART",
            "$$ASCII" if self.form == "ascii" else "$$BINARY",
            f"$$UNITS/{_num(self.units)}",
            "$$VERSION/200",
            f"$$LABEL/1,{label}",
            f"$$DIMENSION/{0.0:.6f},{0.0:.6f},{0.0:.6f},{w:.6f},{d:.6f},{h:.6f}",
            f"$$LAYERS/{self.grid.layers}",
            "// skelslice origin: " + ",".join(_num(v) for v in self._origin)
            + " (scene mm of CLI point 0,0,0) //",
        ]
        if self.meta.get("generator"):
            lines.append(f"// generator: {self.meta['generator']} //")
        head = "\n".join(lines) + "\n$$HEADEREND"
        if self.form == "ascii":
            head += "\n$$GEOMETRYSTART\n"
        self.fh.write(head.encode("ascii", "replace"))

    def _layer(self, k: int, polygons) -> None:
        zq = self._quantise(np.array([(k + 1) * self.layer_height / self.units]))[0]
        if self.form == "short":
            self._check_short(zq, f"layer {k}: z")
        if self._last_z_units is not None and not zq > self._last_z_units:
            raise OutputError(
                f"{self.path}: layer {k} has the same CLI height as layer {k - 1} "
                f"({zq} units of {self.units} mm); use smaller --units than the layer height")
        self._last_z_units = zq
        out: list[bytes] = []
        if self.form == "ascii":
            out.append(f"$$LAYER/{zq:.3f}\n".encode())
        elif self.form == "long":
            out.append(struct.pack("<Hf", CMD_LAYER_LONG, zq))
        else:
            out.append(struct.pack("<HH", CMD_LAYER_SHORT, int(zq)))
        for poly in polygons:
            for i, (coords, outer) in enumerate(rings(poly)):
                q = self._ring(coords, outer, k)
                if q is None:
                    self.dropped_rings += 1
                    if outer:  # holes of a dropped outer ring go with it
                        self.dropped_rings += len(poly.interiors)
                        break
                    continue
                out.append(self._polyline(q, DIR_OUTER if outer else DIR_HOLE))
        self.fh.write(b"".join(out))

    def _end(self) -> None:
        if self.form == "ascii":
            self.fh.write(b"$$GEOMETRYEND\n")

    # ------------------------------------------------------------------ helpers
    def _quantise(self, v: np.ndarray) -> np.ndarray:
        if self.form == "long":
            return v.astype(np.float32).astype(np.float64)
        if self.form == "short":
            return np.rint(v)
        return np.round(v, 3)

    def _check_short(self, v, what: str) -> None:
        lo, hi = float(np.min(v)), float(np.max(v))
        if lo < 0 or hi > 65535:
            bad = lo if lo < 0 else hi
            raise OutputError(
                f"{self.path}: {what} = {bad:.0f} units does not fit the short CLI form (u16, 0..65535 units "
                f"of {self.units} mm); use the long form (--format cli) or larger units")

    def _ring(self, coords: np.ndarray, outer: bool, k: int) -> np.ndarray | None:
        """Quantised closed ring in CLI units (box-relative), or None if degenerate."""
        q = self._quantise((coords - self._origin[:2]) / self.units)
        if self.form == "short":
            self._check_short(q, f"layer {k}: a coordinate")
        keep = np.ones(len(q), dtype=bool)
        keep[1:] = np.any(q[1:] != q[:-1], axis=1)
        q = q[keep]
        if len(q) < 4 or np.any(q[0] != q[-1]):  # 3 distinct points plus the closing one
            return None
        # the shoelace sum over the ring's n distinct vertices (q[n] == q[0]: the
        # shifted coordinates are q[1:], copied as np.roll(., -1) would give them)
        x, y = q[:-1, 0], q[:-1, 1]
        area2 = float(np.dot(x, q[1:, 1].copy()) - np.dot(q[1:, 0].copy(), y))
        if (area2 <= 0) if outer else (area2 >= 0):
            return None
        return q

    def _polyline(self, q: np.ndarray, direction: int) -> bytes:
        n = len(q)
        if self.form == "long":
            return struct.pack("<Hiii", CMD_POLYLINE_LONG, 1, direction, n) + q.astype("<f4").tobytes()
        if self.form == "short":
            return struct.pack("<HHHH", CMD_POLYLINE_SHORT, 1, direction, n) + q.astype("<u2").tobytes()
        text = ",".join(f"{v:.3f}" for v in q.ravel())
        return f"$$POLYLINE/1,{direction},{n},{text}\n".encode()


class CliShortWriter(CliWriter):
    """Binary CLI, short form (u16 coordinates)."""

    name = "cli-short"

    def __init__(self, path, grid, meta=None, force=False, units: float | None = None):
        super().__init__(path, grid, meta, force, form="short", units=units)


class CliAsciiWriter(CliWriter):
    """ASCII CLI."""

    name = "cli-ascii"

    def __init__(self, path, grid, meta=None, force=False, units: float | None = None):
        super().__init__(path, grid, meta, force, form="ascii", units=units)


# ============================================================================= reading
@dataclass
class CliLayer:
    """One layer read back: ``z`` (mm, CLI frame) and its polylines."""

    z: float
    polylines: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (dir, (n, 2) mm)
    hatches: int = 0

    def multipolygon(self) -> shapely.MultiPolygon:
        """The filled region: closed rings combined by nesting (even-odd)."""
        shape = shapely.Polygon()
        closed = [shapely.Polygon(p) for d, p in self.polylines if d != DIR_OPEN and len(p) >= 4]
        for poly in sorted(closed, key=lambda p: -abs(p.area)):
            shape = shapely.symmetric_difference(shape, poly)
        if isinstance(shape, shapely.MultiPolygon):
            return shape
        if isinstance(shape, shapely.Polygon):
            return shapely.MultiPolygon([shape]) if not shape.is_empty else shapely.MultiPolygon()
        return shapely.MultiPolygon([g for g in shape.geoms if isinstance(g, shapely.Polygon)])


@dataclass
class CliFile:
    """A CLI file read back.

    Attributes
    ----------
    binary : bool
    units : float
        mm per unit (coordinates and z in :attr:`layers` are already in mm).
    header : dict
        Every header command (``"UNITS"``, ``"LAYERS"``, ...) to its text value.
    origin : (3,) float64 or None, mm
        The skelslice origin comment: scene position of the CLI origin.
    layers : list of CliLayer
    form : {"long", "short", "ascii"}
    """

    binary: bool
    units: float
    header: dict
    origin: np.ndarray | None
    layers: list[CliLayer]
    form: str


def read_cli(path) -> CliFile:
    """Read a CLI file (ASCII, binary long or binary short, unaligned).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    CliFile
        Coordinates and z converted to mm (value x units), in the file's frame.

    Raises
    ------
    ReadError
        Malformed header or geometry, naming the byte offset or line.
    """
    data = Path(path).read_bytes()
    end = data.find(b"$$HEADEREND")
    if end < 0:
        raise ReadError(f"{path}: no $$HEADEREND: not a CLI file")
    head_text = data[:end].decode("ascii", "replace")
    header: dict[str, str] = {}
    origin = None
    for line in head_text.splitlines():
        m = _ORIGIN_RE.search(line)
        if m:
            origin = np.array([float(v) for v in m.groups()])
        line = re.sub(r"//.*?(//|$)", "", line).strip()
        if line.startswith("$$"):
            cmd, _, value = line[2:].partition("/")
            header[cmd.strip().upper()] = value.strip()
    if "UNITS" not in header:
        raise ReadError(f"{path}: the header has no $$UNITS")
    units = float(header["UNITS"])
    if "ALIGN" in header:
        raise ReadError(f"{path}: $$ALIGN (32-bit aligned) files are not supported by this reader")
    binary = "BINARY" in header
    geom = data[end + len(b"$$HEADEREND"):]
    if binary:
        layers, form = _read_binary(geom, units, path, end + len(b"$$HEADEREND"))
    else:
        layers, form = _read_ascii(geom.decode("ascii", "replace"), units, path), "ascii"
    return CliFile(binary, units, header, origin, layers, form)


def _read_binary(buf: bytes, u: float, path, base: int) -> tuple[list[CliLayer], str]:
    layers: list[CliLayer] = []
    forms: set[str] = set()
    pos, n_buf = 0, len(buf)

    def need(n: int) -> None:
        if pos + n > n_buf:
            raise ReadError(f"{path}: truncated geometry at byte {base + pos}")

    while pos < n_buf:
        need(2)
        (cmd,) = struct.unpack_from("<H", buf, pos)
        pos += 2
        if cmd in (CMD_LAYER_LONG, CMD_LAYER_SHORT):
            fmt = "<f" if cmd == CMD_LAYER_LONG else "<H"
            need(struct.calcsize(fmt))
            (z,) = struct.unpack_from(fmt, buf, pos)
            pos += struct.calcsize(fmt)
            layers.append(CliLayer(float(z) * u))
            forms.add("long" if cmd == CMD_LAYER_LONG else "short")
            continue
        if not layers:
            raise ReadError(f"{path}: command {cmd} before the first layer at byte {base + pos - 2}")
        if cmd in (CMD_POLYLINE_LONG, CMD_POLYLINE_SHORT):
            long = cmd == CMD_POLYLINE_LONG
            meta, coord = ("<iii", "<f4") if long else ("<HHH", "<u2")
            need(struct.calcsize(meta))
            _id, d, n = struct.unpack_from(meta, buf, pos)
            pos += struct.calcsize(meta)
            size = 2 * n * np.dtype(coord).itemsize
            need(size)
            pts = np.frombuffer(buf, dtype=coord, count=2 * n, offset=pos).astype(np.float64).reshape(n, 2) * u
            pos += size
            layers[-1].polylines.append((int(d), pts))
            forms.add("long" if long else "short")
        elif cmd in (CMD_HATCHES_LONG, CMD_HATCHES_SHORT):
            long = cmd == CMD_HATCHES_LONG
            meta, item = ("<ii", 4) if long else ("<HH", 2)
            need(struct.calcsize(meta))
            _id, n = struct.unpack_from(meta, buf, pos)
            pos += struct.calcsize(meta) + 4 * n * item
            need(0)
            layers[-1].hatches += n
        else:
            raise ReadError(f"{path}: unknown binary command {cmd} at byte {base + pos - 2}")
    if len(forms) > 1:
        return layers, "mixed"
    return layers, (forms.pop() if forms else "long")


def _read_ascii(text: str, u: float, path) -> list[CliLayer]:
    text = re.sub(r"//.*?//", "", text, flags=re.S)
    start = text.find("$$GEOMETRYSTART")
    if start < 0:
        raise ReadError(f"{path}: ASCII CLI without $$GEOMETRYSTART")
    layers: list[CliLayer] = []
    for cmd in re.split(r"\$\$", text[start:])[2:]:  # [0] is "", [1] is GEOMETRYSTART
        name, _, args = cmd.partition("/")
        name = name.strip().upper()
        values = [v for v in re.split(r"[,\s]+", args.strip()) if v]
        if name == "GEOMETRYEND":
            break
        if name == "LAYER":
            layers.append(CliLayer(float(values[0]) * u))
        elif name == "POLYLINE":
            if not layers:
                raise ReadError(f"{path}: $$POLYLINE before the first $$LAYER")
            d, n = int(values[1]), int(values[2])
            pts = np.array(values[3:3 + 2 * n], dtype=np.float64)
            if pts.size != 2 * n:
                raise ReadError(f"{path}: $$POLYLINE announces {n} points but has {pts.size // 2}")
            layers[-1].polylines.append((d, pts.reshape(n, 2) * u))
        elif name == "HATCHES":
            if not layers:
                raise ReadError(f"{path}: $$HATCHES before the first $$LAYER")
            layers[-1].hatches += int(values[1])
        else:
            raise ReadError(f"{path}: unknown ASCII CLI command $${name}")
    return layers


__all__ = ["CliWriter", "CliShortWriter", "CliAsciiWriter", "CliFile", "CliLayer", "read_cli",
           "DIR_OUTER", "DIR_HOLE", "DIR_OPEN"]
