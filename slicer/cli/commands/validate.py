"""``skelslice validate``: slice, compare with a meshed manifold3d reference, report."""
from __future__ import annotations

import json
import sys

import click

from validation.parts import validate_part
from validation.union_validate import validate_union
from validation.validate import format_table, validate, write_report

from slicer.atomic import check_destination
from slicer.model.blend import require_sum, require_traceable
from slicer.supports.show import refuse_grouped
from slicer.cli.commands.options import grid_options, load_part_from, part_options, radius_option, trace_options


@click.command("validate")
@click.argument("scene", type=click.Path(dir_okay=False))
@part_options
@grid_options
@click.option("--pixels", type=click.IntRange(min=2), default=512, show_default=True,
              help="Without --pixel-size: a PIXELS x PIXELS image over the model's support box.")
@trace_options
@radius_option
@click.option("--mesh-edge", type=float, default=None,
              help="Reference mesh grid spacing, mm (default: half the pixel pitch).")
@click.option("--layers-checked", type=click.IntRange(min=1), default=8, show_default=True,
              help="Layers compared, evenly spread over the occupied layers.")
@click.option("--contour-tol", type=float, default=1e-3, show_default=True, help="Contour tolerance, mm.")
@click.option("--max-hausdorff", type=float, default=None, help="Fail if a layer's Hausdorff distance exceeds this, mm.")
@click.option("--min-iou", type=float, default=None, help="Fail if a layer's IoU is below this.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write report.json and overlay PNGs to this folder (atomically).")
@click.option("--force", is_flag=True, help="Replace an existing report folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON instead of a table.")
def command(scene, pixel_size, pixels, pixel_size_y, layer_height, bounds, method, bucket, threads, strict, blend,
            radius, mesh_edge, layers_checked, contour_tol, max_hausdorff, min_iou, report_dir, force, as_json,
            solids, clips_inside, clips_outside, repair):
    """Slice SCENE and compare layers with cross-sections of the meshed field
    (for a part: combined with its meshes by manifold3d booleans; with
    --blend union: each strut meshed alone, the struts unioned by manifold3d).

    Prints per layer: IoU and XOR area against the reference, contour
    Hausdorff distance (um and pixels), the reference mesh's own error bound
    in the layer plane, the largest distance of our contour vertices to the
    exact surface, and pixel mismatches against the reference rasterised at
    the pixel centres (unexplained: farther from the exact contour than the
    mesh bound).

    Exit status: 0 if every check passes, 1 if a check or threshold fails,
    2 on invalid input.
    """
    if report_dir is not None:
        check_destination(report_dir, force)   # before any work
    union = require_traceable(blend, "validate", method) == "union"
    part = load_part_from(scene, radius, solids, clips_inside, clips_outside, repair, quiet=as_json)
    refuse_grouped(part, "validate")                       # supports: docs/supports.md
    if union and part.has_meshes:
        require_sum(blend, "validate of a part with meshes")
    run = validate_part if part.has_meshes else (validate_union if union else validate)
    kw = {} if union else {"blend": blend}
    rep = run(part if part.has_meshes else part.skeleton, pixel_size=pixel_size, pixels=pixels,
              pixel_size_y=pixel_size_y, layer_height=layer_height, bounds=bounds or None, method=method,
              bucket=bucket, threads=threads, strict=strict, mesh_edge=mesh_edge, layers_checked=layers_checked,
              tol=contour_tol, max_hausdorff=max_hausdorff, min_iou=min_iou, **kw)
    rep["scene"] = str(scene)
    if report_dir is not None:
        write_report(rep, report_dir, force)
    if as_json:
        click.echo(json.dumps({k: v for k, v in rep.items() if not k.startswith("_")}, indent=1))
    else:
        g = rep["grid"]
        click.echo(f"{scene}: {g['width']} x {g['height']} px x {g['layers']} layers, pixel "
                   f"{g['pixel_size'][0]:.4g} mm; reference mesh edge {rep['settings']['mesh_edge']:.4g} mm")
        click.echo(format_table(rep))
        t = rep["timings"]
        click.echo(f"time: slice {t['slice_s']:.2f} s, reference {t['reference_s']:.2f} s, "
                   f"contours {t['contours_s']:.2f} s, metrics {t['metrics_s']:.2f} s"
                   + (f"; report -> {report_dir}" if report_dir else ""))
    if not rep["passed"]:
        if not rep["layers"]:
            click.echo("no layer has inside pixels: nothing was compared", err=True)
        sys.exit(1)
