"""``skelslice lattice``: generate a strut lattice and write it as a scene file."""
from __future__ import annotations

import click

from slicer.errors import SceneError
from slicer.scene.lattice import check_positive, generate_lattice
from slicer.scene.read import save_scene


class _RadiusSpec(click.ParamType):
    """``R`` or ``R:R_TOP`` (mm) -> ``(r, r_top or None)``."""

    name = "R[:R_TOP]"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).split(":")
        if len(parts) > 2:
            self.fail(f"expected R or R:R_TOP, got {value!r}", param, ctx)
        names = ("R", "R_TOP")
        try:
            radii = [check_positive(_to_float(p, self, param, ctx), n) for p, n in zip(parts, names)]
        except SceneError as exc:
            self.fail(f"{exc} (in {value!r})", param, ctx)
        return radii[0], (radii[1] if len(radii) == 2 else None)


class _CellSize(click.ParamType):
    """``MM`` or ``MX,MY,MZ`` -> float or (3,) tuple."""

    name = "MM[,MY,MZ]"

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value
        parts = value.split(",")
        if len(parts) not in (1, 3):
            self.fail(f"expected one size or three comma-separated sizes, got {value!r}", param, ctx)
        try:
            sizes = [check_positive(_to_float(p, self, param, ctx), "cell size") for p in parts]
        except SceneError as exc:
            self.fail(f"{exc} (in {value!r})", param, ctx)
        return sizes[0] if len(sizes) == 1 else tuple(sizes)


def _to_float(text: str, ptype: click.ParamType, param, ctx) -> float:
    try:
        return float(text)
    except ValueError:
        ptype.fail(f"{text.strip()!r} is not a number", param, ctx)


@click.command("lattice", context_settings={"help_option_names": ["-h", "--help"]})
@click.argument("cell_type", metavar="TYPE")
@click.option("--cells", nargs=3, type=click.IntRange(min=1), required=True,
              metavar="NX NY NZ", help="Number of cells along x, y and z.")
@click.option("--cell-size", type=_CellSize(), required=True,
              help="Cell edge length in mm, or MX,MY,MZ for one per axis.")
@click.option("--radius", "radius_spec", type=_RadiusSpec(), required=True,
              help="Strut radius in mm; R:R_TOP grades it linearly from R at the lowest "
                   "to R_TOP at the highest node along --axis (struts are tapered).")
@click.option("--axis", type=click.Choice(["x", "y", "z"]), default="z", show_default=True,
              help="Grading axis for R:R_TOP.")
@click.option("--origin", nargs=3, type=float, default=(0.0, 0.0, 0.0), show_default=True,
              metavar="X Y Z", help="Lowest corner of the cell grid, mm.")
@click.option("--envelope-box", nargs=6, type=float, default=None,
              metavar="X0 Y0 Z0 X1 Y1 Z1",
              help="Keep only struts with both ends inside this box (mm).")
@click.option("--envelope-cylinder", nargs=5, type=float, default=None,
              metavar="CX CY R Z0 Z1",
              help="Keep only struts with both ends inside this z-aligned cylinder (mm).")
@click.option("--degree", type=int, default=6, show_default=True, help="Kernel degree (even).")
@click.option("--sigma", type=float, default=2.0, show_default=True,
              help="Kernel support factor (> 1).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True,
              help="Scene file to write: .json (scene v1) or .obj (polylines).")
def command(cell_type, cells, cell_size, radius_spec, axis, origin, envelope_box,
            envelope_cylinder, degree, sigma, output):
    """Generate a strut lattice of TYPE cells and write it as a scene.

    TYPE is one of: cubic, bcc, fcc, octet, kelvin, diamond, or several joined
    by '+' (e.g. bcc+cubic). Shared nodes and struts between cells are merged.

    Example: skelslice lattice octet --cells 4 4 4 --cell-size 5 --radius 0.4:0.8 -o octet.json
    """
    if envelope_box and envelope_cylinder:
        raise click.UsageError("give at most one of --envelope-box and --envelope-cylinder")
    envelope = None
    if envelope_box:
        envelope = ("box", envelope_box[:3], envelope_box[3:])
    elif envelope_cylinder:
        cx, cy, r, z0, z1 = envelope_cylinder
        envelope = ("cylinder", (cx, cy), r, z0, z1)
    radius, radius_top = radius_spec
    skel = generate_lattice(cell_type, cells, cell_size, radius, radius_top=radius_top,
                            grading_axis=axis, envelope=envelope, origin=origin,
                            degree=degree, sigma=sigma)
    save_scene(skel, output)
    lo, hi = skel.nodes.min(axis=0), skel.nodes.max(axis=0)
    click.echo(f"{cell_type} lattice: {skel.n_nodes} nodes, {skel.n_segments} struts, "
               f"node bbox [{lo[0]:g}, {lo[1]:g}, {lo[2]:g}]..[{hi[0]:g}, {hi[1]:g}, {hi[2]:g}] mm, "
               f"radius {skel.radii.min():g}..{skel.radii.max():g} mm -> {output}")
