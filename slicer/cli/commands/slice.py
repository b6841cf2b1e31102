"""``skelslice slice``: scene to layer images (or contours)."""
from __future__ import annotations

import click

from formats.base import check_destination
from formats.estimate import PrintEstimate

from slicer.job.config import config_option
from slicer.scale.executors import executor_info
from slicer.job.run import check_not_input, run_slice
from slicer.parts.part import Part
from slicer.scale.tileplan import auto_budget, parse_size
from slicer.cli.commands.supports import pop_support_options, supports_for, supports_options
from slicer.cli.commands.info import scene_stats
from slicer.cli.commands.options import (grid_options, job_from, load_part_from, part_inputs, part_options, print_options, radius_option,
                      scale_options, trace_options)


@click.command("slice")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(), help="Output (a folder for PNG stacks).")
@part_options
@grid_options
@trace_options
@click.option("--format", "fmt", type=str, default=None, help="Output format (default: from the output name; png).")
@click.option("--contour-tol", type=float, default=1e-3, show_default=True,
              help="Contour accuracy for contour formats (cli, cli-ascii, cli-short, 3mf, svg), mm.")
@click.option("--contours", "contours", type=click.Path(dir_okay=False), default=None,
              help="Also write the layer contours (vertices on the surface to --contour-tol) to this "
                   "file: .geojson (a FeatureCollection) or .json.")
@print_options
@radius_option
@supports_options
@click.option("--force", is_flag=True, help="Replace an existing output (never the input).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
@scale_options
@click.option("--dry-run", is_flag=True, help="Print the grid, tile plan, memory and time estimates; write nothing.")
@click.option("--verbose", "-v", is_flag=True, help="Print the tile plan before slicing (on stderr).")
@config_option
def command(scene, out, radius, quiet, dry_run, verbose, solids, clips_inside, clips_outside, repair, **options):
    """Slice SCENE into layer images: every voxel centre classified exactly.

    SCENE is a lattice (.json, .obj, .3mf), a part (a .json scene with meshes,
    or a .3mf build with mesh objects and clipping) or a mesh (.stl, .ply);
    --solid, --clip-inside and --clip-outside add meshes to it.
    """
    check_not_input(out, *part_inputs(scene, dict(solids=solids, clips_inside=clips_inside,
                                                  clips_outside=clips_outside)))
    check_destination(out, options["force"])
    mm = options["max_memory"]
    budget = auto_budget() if mm == "auto" else parse_size(mm)
    executor_info(options["executor"], options["workers"], options["scheduler"])   # --scheduler without dask
    job = job_from(options, max_memory=budget, scene_name=str(scene))
    supports = pop_support_options(options)
    skel = load_part_from(scene, radius, solids, clips_inside, clips_outside, repair, quiet)
    supported = supports_for(skel, supports, job, job.trace.blend, quiet)
    if supported is not skel:
        skel = Part(supported, (), skel.source)         # --supports auto
    report = (lambda text: click.echo(text, err=True)) if (verbose and not dry_run) else None
    summary = run_slice(skel, out, job, dry_run=dry_run, report=report)
    if dry_run:
        _print_dry_run(skel, scene, out, summary, job)
        return
    if not quiet:
        click.echo(
            f"{summary['width']} x {summary['height']} px x {summary['layers']} layers -> {out} [{summary['format']}] "
            f"({job.trace.method}: trace {summary['trace_seconds']:.2f} s, {summary['evaluations']:,} evaluations, "
            f"write {summary['write_seconds']:.2f} s)")
        if summary.get("estimate"):
            click.echo(PrintEstimate.from_dict(summary["estimate"]).describe())


def _print_dry_run(skel, scene, out, summary, job) -> None:
    """The ``--dry-run`` report: scene warnings, grid, tile plan, estimates."""
    plan = summary["plan"]
    g = plan["grid"]
    s = job.scale
    click.echo("dry run: nothing is written")
    click.echo(f"scene:     {scene} ({skel.describe()})")
    click.echo(f"output:    {out} [{summary['format']}]")
    where = s.executor + (f" at {s.scheduler}" if s.scheduler else "") + (f", {s.workers} workers" if s.workers else "")
    click.echo(f"executor:  {where}")
    click.echo(summary["plan_text"])
    if summary.get("estimate"):
        click.echo(f"estimate:  {PrintEstimate.from_dict(summary['estimate']).describe()} "
                   f"(the grid's layers, an upper bound; resin once sliced)")
    if skel.skeleton is not None:
        for w in scene_stats(skel.skeleton, g["pixel_size"][0], job.trace.blend)["warnings"]:
            click.echo(f"warning:   {w['message']}")
