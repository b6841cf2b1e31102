"""``skelslice render``: transparent (or opaque) picture of a scene, every crossing found."""
from __future__ import annotations

import click

from slicer.render.rendering import CAMERAS, VIEWS
from slicer.render.output import run_render
from slicer.model.blend import require_sum
from slicer.job.spec import SliceJob
from slicer.cli.commands.supports import pop_support_options, supports_for, supports_options
from slicer.cli.commands.options import blend_option, load_part_from, part_options, radius_option


@click.command("render")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False), help="Output PNG.")
@click.option("--size", type=int, nargs=2, default=(700, 700), show_default=True, metavar="W H",
              help="Image width and height, pixels.")
@click.option("--view", type=click.Choice(list(VIEWS)), default="iso", show_default=True,
              help="Direction to look from (ignored with --eye/--target).")
@click.option("--camera", type=click.Choice(list(CAMERAS)), default="ortho", show_default=True,
              help="Projection.")
@click.option("--fov", type=float, default=35.0, show_default=True,
              help="Vertical field of view, degrees (perspective).")
@click.option("--eye", type=float, nargs=3, default=None, metavar="X Y Z", help="Camera position, mm.")
@click.option("--target", type=float, nargs=3, default=None, metavar="X Y Z", help="Point looked at, mm.")
@click.option("--opacity", type=float, default=0.3, show_default=True,
              help="Opacity of each crossing (entry and exit surfaces both count).")
@click.option("--max-opacity", type=float, default=0.99, show_default=True,
              help="Stop a ray once its accumulated opacity reaches this (1: never).")
@click.option("--opaque", is_flag=True, help="First crossing only, fully opaque.")
@click.option("--tolerance", type=float, default=None, metavar="MM",
              help="Crossing tolerance (default: 1e-4 of the model's support box diagonal).")
@click.option("--roots-out", type=click.Path(dir_okay=False), default=None, metavar="FILE.npz",
              help="Also write every crossing of every ray (origin, direction, count, roots).")
@click.option("--bisection", is_flag=True, help="Refine crossings by bisection instead of cubic Hermite steps.")
@click.option("--strict", is_flag=True, help="Lipschitz bounds only (no reliance on per-primitive unimodality).")
@click.option("--transparent", is_flag=True, help="RGBA PNG with a transparent background (default: on white).")
@click.option("--bucket", type=click.IntRange(min=1), default=16, show_default=True,
              help="Screen bucket edge, pixels.")
@click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores).")
@radius_option
@part_options
@blend_option
@supports_options
@click.option("--force", is_flag=True, help="Replace existing outputs.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
def command(scene, out, size, view, camera, fov, eye, target, opacity, max_opacity, opaque, tolerance,
            roots_out, bisection, strict, transparent, bucket, threads, radius, solids, clips_inside, clips_outside,
            repair, blend, force, quiet, **support_kw):
    """Render SCENE to a PNG: every crossing of every ray, shaded and
    composited front to back as semi-transparent layers (a part's meshes too)."""
    require_sum(blend, "rendering (the renderer's ray kernels)")
    skel = load_part_from(scene, radius, solids, clips_inside, clips_outside, repair, quiet)
    skel = supports_for(skel, pop_support_options(support_kw), SliceJob.from_options(pixel_size=0.05), blend, quiet)
    st = run_render(skel, out, roots_out=roots_out, force=force, transparent=transparent, size=size,
                    view=view, camera=camera, fov=fov, eye=eye or None, target=target or None,
                    opacity=opacity, max_opacity=max_opacity, opaque=opaque, tolerance=tolerance,
                    bisection=bisection, strict=strict, bucket=bucket, threads=threads)
    if st["roots"] == 0:
        click.echo(f"warning: nothing is visible: no ray of the {st['width']} x {st['height']} image crosses the "
                   f"surface (a framing that misses the model, --eye/--target looking away from it, or struts "
                   f"far thinner than a pixel); the image is empty", err=True)
    if not quiet:
        click.echo(
            f"{st['width']} x {st['height']} px -> {out} ({st['camera']}, {st['seconds']:.2f} s, "
            f"{st['roots']:,} crossings, {st['evaluations']:,} evaluations: {st['isolate_evaluations']:,} "
            f"isolate + {st['refine_evaluations']:,} refine ({st['refine']}) + {st['shade_evaluations']:,} "
            f"shade; {st['rays_cut']:,} rays stopped by the opacity cut-off"
            + (f"; roots -> {roots_out}" if roots_out else "") + ")")
