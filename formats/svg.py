"""SVG contours: one file per stack, one group per layer, one path per region.

Layout::

    <svg xmlns="http://www.w3.org/2000/svg" width="{W}mm" height="{D}mm" viewBox="0 0 W D"
         xmlns:inkscape=... xmlns:skelslice="urn:skelslice:svg:1"
         skelslice:origin="X0 Y1" skelslice:layers="N" skelslice:layer-height="H">
      <rect id="background" x="0" y="0" width="W" height="D" fill="#000000"/>
      <g id="layer00000" inkscape:groupmode="layer" inkscape:label="layer 0, z 0.025 mm"
         skelslice:z="0.025" skelslice:ztop="0.05" fill="#ffffff" fill-rule="evenodd" stroke="none">
        <path d="M x,y L x,y ... Z M ... Z"/>     one per region: its outline and its holes
      </g>
      ...
    </svg>

* One SVG user unit is 1 mm; the drawing covers the job's box. The image
  shows the part **seen from above**: x to the right, y up the page
  (SVG x = x - X0, SVG y = Y1 - y, where ``skelslice:origin`` = X0 Y1 is the
  box's top-left corner in scene mm), like the PNG stack.
* Solid is white on a black background (as in the image stacks).
* Each region (an outer ring and its holes) is **one** ``<path>``, holes
  wound opposite to the outline, with ``fill-rule="evenodd"``: renderers that
  honour the rule and renderers that fall back to the default ``nonzero``
  both leave the holes empty (a hole drawn as a separate path would be
  filled by any generic renderer).
* Every layer is a group (Inkscape shows them as layers); all are visible,
  so a browser shows the union of the layers, a top view. To view one layer,
  hide the others, or select the group ``#layerNNNNN``. Empty layers are
  empty groups.
* Coordinates have 6 decimals (1 nm); the same job gives byte-identical files.
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

from formats.contour_base import ContourWriter, rings

SVG_NS = "http://www.w3.org/2000/svg"
INKSCAPE_NS = "http://www.inkscape.org/namespaces/inkscape"
SKELSLICE_NS = "urn:skelslice:svg:1"


def _c(v: float) -> str:
    s = f"{v:.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


class SvgWriter(ContourWriter):
    """Single SVG file with a group per layer (see the module docstring)."""

    name = "svg"
    suffix = ".svg"

    def _begin(self) -> None:
        x0, y0, _, x1, y1, _ = self.box()
        self._x0, self._y1 = x0, y1
        w, d = _c(x1 - x0), _c(y1 - y0)
        title = self.meta.get("scene", "")
        gen = self.meta.get("generator", "skelslice")
        self.fh.write((
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<svg xmlns="{SVG_NS}" xmlns:inkscape="{INKSCAPE_NS}" xmlns:skelslice="{SKELSLICE_NS}" '
            f'version="1.1" width="{w}mm" height="{d}mm" viewBox="0 0 {w} {d}" '
            f'skelslice:origin="{_c(x0)} {_c(y1)}" skelslice:layers="{self.grid.layers}" '
            f'skelslice:layer-height="{self.layer_height!r}">\n'
            f' <!-- {_comment(gen)}: layer sections seen from above, 1 unit = 1 mm; '
            f'scene x = X0 + svg x, scene y = Y1 - svg y (skelslice:origin = X0 Y1) -->\n'
            + (f" <title>{_text(str(title))}</title>\n" if title else "")
            + f' <rect id="background" x="0" y="0" width="{w}" height="{d}" fill="#000000"/>\n'
        ).encode("utf-8"))

    def _layer(self, k: int, polygons) -> None:
        z = self.z_section(k)
        head = (f' <g id="layer{k:05d}" inkscape:groupmode="layer" '
                f'inkscape:label={quoteattr(f"layer {k}, z {_c(z)} mm")} skelslice:z="{z!r}" '
                f'skelslice:ztop="{self.z_top(k)!r}" fill="#ffffff" fill-rule="evenodd" stroke="none"')
        if not polygons:
            self.fh.write((head + "/>\n").encode())
            return
        out = [head + ">\n"]
        for poly in polygons:
            parts = []
            for coords, _outer in rings(poly):
                xs = coords[:-1, 0] - self._x0
                ys = self._y1 - coords[:-1, 1]
                pts = [f"{_c(x)},{_c(y)}" for x, y in zip(xs.tolist(), ys.tolist())]
                parts.append("M " + pts[0] + " L " + " ".join(pts[1:]) + " Z")
            out.append('  <path d="' + " ".join(parts) + '"/>\n')
        out.append(" </g>\n")
        self.fh.write("".join(out).encode())

    def _end(self) -> None:
        self.fh.write(b"</svg>\n")


def _text(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _comment(s: str) -> str:
    return _text(s).replace("--", "- -")


__all__ = ["SvgWriter"]
