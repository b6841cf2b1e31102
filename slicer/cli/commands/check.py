"""``skelslice check``: printability report of a scene's exact slices (or of a written output).

Exit status: 0 when nothing blocks (nothing is printed when nothing is
found at all), 1 when something blocks (``--fail-on``), 2 on bad input.
"""
from __future__ import annotations

from pathlib import Path

import click

from formats.readback import kind_of, open_stack

from slicer.atomic import check_destination
from slicer.job.config import config_option
from slicer.errors import OptionError
from slicer.job.run import check_not_input, slice_job
from slicer.printability import DEFAULT_FAIL_ON, KINDS, CheckOptions, check_stack, model_layers, read_layers
from slicer.scene.read import load_scene
from slicer.scale.tileplan import auto_budget, parse_size
from slicer.cli.commands.supports import add_supports, pop_support_options, support_report, supports_options
from slicer.cli.commands.options import grid_options, job_from, print_options, radius_option, scale_options, trace_options

#: slice options that make no sense for an output that is already sliced
_SLICE_ONLY = ("pixel_size", "pixel_size_y", "layer_height", "bounds", "printer", "at", "radius")


def check_options(f):
    """The check's thresholds and blocking rules (shared with ``preview``)."""
    for d in reversed([
        click.option("--min-feature", type=float, default=0.0, show_default=True, metavar="MM",
                     help="Report struts printed thinner than this (and always those thinner than the pixel)."),
        click.option("--min-island-area", type=float, default=0.0, show_default=True, metavar="MM2",
                     help="Smaller islands are listed but do not block."),
        click.option("--min-trap-volume", type=float, default=0.0, show_default=True, metavar="MM3",
                     help="Smaller resin traps are listed but do not block."),
        click.option("--max-area-jump", type=float, default=None, metavar="MM2",
                     help="Report layer-to-layer area increases above this (peel forces) as 'jumps'."),
        click.option("--fail-on", default=",".join(DEFAULT_FAIL_ON), show_default=True, metavar="KINDS",
                     help=f"Comma-separated kinds that block (exit status 1): {', '.join(KINDS)}, or none."),
    ]):
        f = d(f)
    return f


def options_of(kw: dict) -> CheckOptions:
    """The :class:`CheckOptions` of a command's keyword arguments (removes them from ``kw``)."""
    return CheckOptions.from_values(kw.pop("min_feature"), kw.pop("min_island_area"), kw.pop("min_trap_volume"),
                                    kw.pop("max_area_jump"), kw.pop("fail_on"))


def is_output(path) -> bool:
    """True when ``path`` is an image output skelslice reads back (not a scene)."""
    return kind_of(path) is not None


def checked_stack(scene, radius, options: dict, progress=None, supports: dict | None = None):
    """The layer stack (and skeleton, or None) of a scene sliced in memory or of an output read back.

    Returns
    -------
    stack : slicer.printability.LayerStack
    skel : Skeleton or None
    result : SliceResult or None
    resolved : ResolvedJob or None
    """
    if Path(scene).suffix.lower() in (".cli", ".svg"):
        open_stack(scene)                               # refused by name: contours, not layer images
    if is_output(scene):
        given = [n for n in _SLICE_ONLY if options.get(n) not in (None, ())] + (["radius"] if radius else [])
        if supports and supports.get("supports") == "auto":
            given.append("supports")
        if given:
            raise OptionError(f"{scene} is already sliced: --{given[0].replace('_', '-')} applies to scenes only")
        return read_layers(scene), None, None, None
    mm = options.get("max_memory")
    if mm is not None:
        options["max_memory"] = auto_budget() if mm == "auto" else parse_size(mm)
    job = job_from(options, scene_name=str(scene))
    skel = load_scene(scene, radius=radius)
    skel = add_supports(skel, supports or {}, job, options.get("blend") or "sum")     # --supports auto
    res, resolved = slice_job(skel, job, progress=progress)
    return model_layers(res, resolved.settings, source=str(scene)), skel, res, resolved


@click.command("check")
@click.argument("scene", type=click.Path())
@grid_options
@trace_options
@print_options
@radius_option
@check_options
@supports_options
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="Write the whole report as JSON (islands, thin_segments, traps, areas, estimate).")
@click.option("--force", is_flag=True, help="Replace an existing --json file.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing; the exit status tells.")
@click.option("--verbose", "-v", is_flag=True, help="Also print the summary when nothing is found.")
@scale_options
@config_option
def command(scene, radius, json_out, force, quiet, verbose, **options):
    """Check SCENE for what fails on a resin printer: islands that start in
    mid-air, struts thinner than the pixel or --min-feature, resin traps
    (closed cavities and suction cups), layer areas and area jumps, print
    time and resin. SCENE may also be an output skelslice wrote (PNG folder,
    zip, sl1, sl1s, goo, nanodlp): then its layers are checked as they are.

    Exit status 0: nothing blocks (quiet when nothing is found); 1: something
    in --fail-on was found; 2: bad input.
    """
    opts = options_of(options)
    supports = pop_support_options(options)
    if json_out is not None:
        check_not_input(json_out, scene)
        check_destination(Path(json_out), force)
    blend = options.get("blend") or "sum"
    stack, skel, res, _resolved = checked_stack(scene, radius, options, supports=supports)
    report = check_stack(stack, skel, opts, blend=blend)
    sup = support_report(skel, res)                          # a supported scene: counts and resin
    if sup is not None:
        report.info["supports"] = {k: v for k, v in sup.items() if k != "line"}
    if json_out is not None:
        report.write_json(json_out, force)
    if not quiet:
        text = report.text()
        if text:
            click.echo(text)
        elif verbose:
            click.echo(f"{scene}: nothing found\n{report.summary_line()}")
        if sup is not None and (text or verbose):
            click.echo(sup["line"])
    if not report.ok:
        raise SystemExit(1)
