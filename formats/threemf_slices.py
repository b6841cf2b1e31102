"""3MF Slice Extension: the contours as a slice stack in a 3MF package.

Layout (3MF core 1.x + Slice Extension v1.0, namespace ``s`` =
``http://schemas.microsoft.com/3dmanufacturing/slice/2015/07``)::

    [Content_Types].xml
    _rels/.rels                     -> /3D/3dmodel.model (StartPart)
    3D/3dmodel.model
        <model unit="millimeter" requiredextensions="s">
          <resources>
            <s:slicestack id="1" zbottom="Z0">
              <s:slice ztop="...">            one per layer, ztop strictly increasing
                <s:vertices><s:vertex x y/>...</s:vertices>
                <s:polygon startv="i"><s:segment v2="j"/>...</s:polygon>
              </s:slice>
              ...
            </s:slicestack>
            <object id="2" type="model" s:slicestackid="1" s:meshresolution="lowres">
              <mesh> the job's box (12 triangles) </mesh>
            </object>
          </resources>
          <build><item objectid="2"/></build>
        </model>

* Coordinates are scene mm (no translation); ``ztop`` of layer k is the
  layer's upper surface ``z_k + h/2`` and ``zbottom`` the bottom of layer 0
  (see :mod:`formats.contour_base`). Every layer has a ``<s:slice>``, empty
  layers included (the extension requires it).
* Each ring is one closed ``<s:polygon>`` (last segment back to ``startv``),
  outer rings counter-clockwise and holes clockwise, as the core's positive
  fill rule needs.
* The object's mesh is the job's box marked ``lowres``: the slices are the
  geometry, and ``requiredextensions="s"`` makes a consumer without the
  Slice Extension refuse the file instead of printing a box.
* The stack lives in the root model part, streamed while layers arrive (the
  object and build follow it). Entries are deflated with fixed timestamps, so
  the same job gives byte-identical files.
* Numbers are written with :func:`repr` (shortest round-trip float text).
"""
from __future__ import annotations

import zipfile
from xml.sax.saxutils import quoteattr

from formats.contour_base import ContourWriter, rings

SLICE_NS = "http://schemas.microsoft.com/3dmanufacturing/slice/2015/07"
CORE_NS = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
MODEL_PATH = "3D/3dmodel.model"
_DATE = (1980, 1, 1, 0, 0, 0)

CONTENT_TYPES = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
 <Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
 <Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>
</Types>
"""
RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
 <Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>
"""


def _n(x: float) -> str:
    return repr(float(x))


class ThreeMFSliceWriter(ContourWriter):
    """3MF package with one slice stack (see the module docstring)."""

    name = "3mf"
    suffix = ".3mf"

    def _entry(self, name: str) -> zipfile.ZipInfo:
        info = zipfile.ZipInfo(name, date_time=_DATE)
        info.compress_type = zipfile.ZIP_DEFLATED
        info.external_attr = 0o644 << 16
        return info

    def _begin(self) -> None:
        self._zip = zipfile.ZipFile(self.fh, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6)
        self._zip.writestr(self._entry("[Content_Types].xml"), CONTENT_TYPES)
        self._zip.writestr(self._entry("_rels/.rels"), RELS)
        self._model = self._zip.open(self._entry(MODEL_PATH), "w", force_zip64=True)
        meta = "".join(
            f' <metadata name={quoteattr(k)}>{_escape(str(v))}</metadata>\n'
            for k, v in (("Application", self.meta.get("generator", "skelslice")),
                         ("Title", self.meta.get("scene", ""))) if v)
        zb = self.box()[2]
        self._write(
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<model xmlns="{CORE_NS}" xmlns:s="{SLICE_NS}" unit="millimeter" xml:lang="en-US" '
            f'requiredextensions="s">\n{meta} <resources>\n'
            f'  <s:slicestack id="1" zbottom="{_n(zb)}">\n')

    def _write(self, text: str) -> None:
        self._model.write(text.encode("utf-8"))

    def _layer(self, k: int, polygons) -> None:
        ztop = _n(self.z_top(k))
        if not polygons:
            self._write(f'   <s:slice ztop="{ztop}"/>\n')
            return
        verts: list[str] = []
        polys: list[str] = []
        nv = 0
        for poly in polygons:
            for coords, _outer in rings(poly):
                pts = coords[:-1]  # the closing point is the segment back to startv
                m = len(pts)
                verts.extend(f'<s:vertex x="{_n(x)}" y="{_n(y)}"/>' for x, y in pts.tolist())
                segs = "".join(f'<s:segment v2="{nv + j}"/>' for j in range(1, m))
                polys.append(f'<s:polygon startv="{nv}">{segs}<s:segment v2="{nv}"/></s:polygon>')
                nv += m
        self._write(f'   <s:slice ztop="{ztop}">\n    <s:vertices>' + "".join(verts)
                    + "</s:vertices>\n    " + "\n    ".join(polys) + "\n   </s:slice>\n")

    def _end(self) -> None:
        x0, y0, z0, x1, y1, z1 = self.box()
        corners = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
        # outward-facing (counter-clockwise seen from outside) box triangles
        tris = [(0, 2, 1), (1, 2, 3), (4, 5, 6), (5, 7, 6), (0, 1, 4), (1, 5, 4),
                (2, 6, 3), (3, 6, 7), (0, 4, 2), (2, 4, 6), (1, 3, 5), (3, 7, 5)]
        v = "".join(f'<vertex x="{_n(x)}" y="{_n(y)}" z="{_n(z)}"/>' for x, y, z in corners)
        t = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in tris)
        self._write(
            "  </s:slicestack>\n"
            '  <object id="2" type="model" name="skelslice slices" s:slicestackid="1" '
            's:meshresolution="lowres">\n'
            f"   <mesh><vertices>{v}</vertices><triangles>{t}</triangles></mesh>\n"
            "  </object>\n </resources>\n"
            ' <build><item objectid="2"/></build>\n</model>\n')
        self._model.close()
        self._zip.close()

    def abort(self) -> None:
        z = getattr(self, "_zip", None)
        if z is not None:
            try:
                if getattr(self, "_model", None) is not None and not self._model.closed:
                    self._model.close()
                z.close()
            except Exception:  # the file is being thrown away
                pass
        super().abort()


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


__all__ = ["ThreeMFSliceWriter"]
