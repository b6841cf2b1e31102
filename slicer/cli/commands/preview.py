"""``skelslice preview``: one self-contained HTML layer viewer of an output or a scene."""
from __future__ import annotations

from pathlib import Path

import click
from tqdm import tqdm

from slicer.atomic import check_destination
from slicer.model.blend import require_sum
from slicer.job.config import config_option
from slicer.contours import iter_contours
from slicer.job.run import check_not_input, plate_placement
from slicer.viewer.page import PreviewBuilder, contours_of_polygons, png_data_uri, read_contours
from slicer.printability import check_stack
from slicer.cli.commands.supports import pop_support_options, supports_options
from slicer.supports.groups import is_grouped
from slicer.supports.show import render_scene
from slicer.scene.read import load_scene
from slicer.tracer.slicing import SliceResult
from slicer.cli.commands.check import check_options, checked_stack, is_output, options_of
from slicer.cli.commands.options import grid_options, print_options, radius_option, trace_options

#: default contour tolerance of a scene's preview: the traced pixel / this
CONTOUR_TOL_PIXELS = 8


@click.command("preview")
@click.argument("source", type=click.Path())
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="The HTML file to write.")
@grid_options
@trace_options
@print_options
@radius_option
@check_options
@supports_options
@click.option("--no-check", is_flag=True, help="Do not run the printability check (no findings marked).")
@click.option("--contours", "contours_file", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Overlay the contours of this file (written by `slice --contours`, .geojson or .json).")
@click.option("--no-contours", is_flag=True, help="Do not compute the contours of a scene.")
@click.option("--contour-tol", type=float, default=None, metavar="MM",
              help="Accuracy of contours computed from a scene, mm (default: an eighth of the pixel; "
                   "the page draws them simplified to a fifth of a pixel).")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False), default=None, metavar="SCENE",
              help="With an output: the scene it was sliced from, for the transparent render "
                   "(and the thin-strut check of a stack in scene coordinates).")
@click.option("--render-size", type=click.IntRange(min=16, max=2048), default=360, show_default=True,
              help="Size of the transparent render, pixels.")
@click.option("--no-render", is_flag=True, help="No transparent render of the scene.")
@click.option("--force", is_flag=True, help="Replace an existing output.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
@config_option
def command(source, out, radius, no_check, contours_file, no_contours, contour_tol, scene_file, render_size,
            no_render, force, quiet, **options):
    """Write a self-contained HTML viewer (-o view.html) of SOURCE: an output
    skelslice wrote (PNG folder, zip, sl1, sl1s, goo, nanodlp) or a scene,
    sliced in memory with the slice options. Layer slider and keys, zoom and
    pan, contours, the check's findings on their layers, a per-layer area
    plot and a transparent render of the part. Opens from disk, no network.
    """
    opts = options_of(options)
    supports = pop_support_options(options)
    blend = options.get("blend") or "sum"
    if blend != "sum" and not is_output(source):
        if not no_contours and contours_file is None:
            require_sum(blend, "preview's contour overlay", "pass --no-contours (or --contours FILE)")
        if not no_render:
            require_sum(blend, "preview's scene render", "pass --no-render")
    check_not_input(out, source, scene_file, contours_file)
    check_destination(Path(out), force)
    stack, skel, res, resolved = checked_stack(source, radius, options, supports=supports)
    scene = skel if skel is not None else (load_scene(scene_file, radius=radius) if scene_file else None)
    builder = PreviewBuilder(stack)
    report = None
    if no_check:
        for k, img in enumerate(stack):
            builder.add(k, img)
    else:
        thin_skel = skel if skel is not None else (scene if stack.frame == "scene" else None)
        report = check_stack(stack, thin_skel, opts, on_layer=builder.add, blend=blend)
    contours = None
    if contours_file is not None:
        contours = read_contours(contours_file)
    elif skel is not None and not no_contours and not is_grouped(skel) and isinstance(res, SliceResult):
        placement = plate_placement(res, resolved.settings)
        tol = contour_tol if contour_tol is not None else min(res.grid.pixel_size) / CONTOUR_TOL_PIXELS
        items = iter_contours(skel, res, tol, placement=placement)
        contours = contours_of_polygons(tqdm(items, total=stack.grid.layers, unit="layer", desc="contours",
                                             disable=None, leave=False))
    renders = []
    if scene is not None and not no_render:
        img = render_scene(scene, size=(render_size, render_size), view="iso").image(transparent=True)
        caption = "transparent render of the scene (iso view" + ("; supports in orange)" if is_grouped(scene) else ")")
        renders.append({"caption": caption, "src": png_data_uri(img)})
    size = builder.write(out, force, title=Path(source).name, report=report, contours=contours, renders=renders,
                         job=_job_text(source, stack))
    if not quiet:
        g = stack.grid
        found = "" if report is None else (" nothing found" if report.clean else " findings: " + ", ".join(
            f"{n} {k}" for k, n in report.counts.items() if n))
        click.echo(f"{g.width} x {g.height} px x {len(builder.layers)} layers -> {out} ({size / 1e6:.2f} MB;"
                   f"{found})")


def _job_text(source, stack) -> str:
    g, s = stack.grid, stack.settings
    parts = [f"{source}", f"{stack.frame} coordinates", f"pixel {g.pixel_size[0]:g} x {g.pixel_size[1]:g} mm",
             f"layer {g.layer_height:g} mm"]
    if stack.printer is not None:
        parts.append(f"printer {stack.printer.label}")
        if stack.frame == "plate":
            parts.append(f"window at plate row {stack.window[0]}, column {stack.window[1]} of "
                         f"{stack.full_shape[1]} x {stack.full_shape[0]} px")
    if s is not None:
        parts.append(f"exposure {s.exposure:g} s, bottom {s.bottom_exposure:g} s x {s.bottom_layers}")
        if s.aa > 1 or s.aa_z:
            parts.append(f"anti-aliasing {s.aa}x{s.aa}{' + z' if s.aa_z else ''}")
    return "; ".join(parts)
