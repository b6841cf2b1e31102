"""``skelslice slice``: scene to layer images."""
from __future__ import annotations

from pathlib import Path

import click

from slicer.config import config_option


@click.command("slice")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(), help="Output (a folder for PNG stacks).")
@click.option("--pixel-size", type=float, default=None,
              help="Pixel pitch along x (and y), mm (required unless --printer sets it).")
@click.option("--pixel-size-y", type=float, default=None, help="Pixel pitch along y, mm (default: --pixel-size).")
@click.option("--layer-height", type=float, default=None, help="Layer height, mm (default: --pixel-size).")
@click.option("--bounds", type=float, nargs=6, default=None, metavar="X0 Y0 Z0 X1 Y1 Z1",
              help="Box to slice, mm (default: the whole surface plus one empty voxel of margin).")
@click.option("--method", type=click.Choice(["interval", "sampling", "segment"]), default="interval",
              show_default=True, help="Tracing method (sampling and segment are the paper's baselines).")
@click.option("--bucket", type=click.IntRange(min=0), default=64, show_default=True,
              help="Bucket edge in pixels (0: one global primitive list).")
@click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores).")
@click.option("--strict", is_flag=True, help="Do not rely on per-primitive unimodality (Lipschitz bounds only).")
@click.option("--format", "fmt", type=str, default=None, help="Output format (default: from the output name; png).")
@click.option("--contour-tol", type=float, default=1e-3, show_default=True,
              help="Contour accuracy for contour formats (cli, cli-ascii, cli-short, 3mf, svg), mm.")
@click.option("--contours", "contours", type=click.Path(dir_okay=False), default=None,
              help="Also write the layer contours (vertices on the surface to --contour-tol) to this "
                   "file: .geojson (a FeatureCollection) or .json.")
@click.option("--printer", type=str, default=None,
              help="Printer profile (see `skelslice printers`): pixel pitch, plate, orientation, exposure; "
                   "the model is centred on the plate, bottom at Z = 0.")
@click.option("--at", type=float, nargs=2, default=None, metavar="X Y",
              help="With --printer: centre of the model's footprint on the plate, mm.")
@click.option("--aa", type=int, default=1, show_default=True,
              help="Anti-aliasing: N x N sub-pixel samples per pixel (1-16), grey = coverage.")
@click.option("--aa-z", is_flag=True, help="Anti-aliasing in z: exact sub-layer coverage of each voxel.")
@click.option("--gamma", type=float, default=1.0, show_default=True,
              help="Grey = coverage^g / (coverage^g + (1 - coverage)^g); 50 % coverage is always 128.")
@click.option("--exposure", type=float, default=None, help="Normal layer exposure, s (default: printer's).")
@click.option("--bottom-exposure", type=float, default=None, help="Bottom layer exposure, s (default: printer's).")
@click.option("--bottom-layers", type=int, default=None,
              help="Bottom layers (Prusa: faded layers) (default: printer's).")
@click.option("--radius", type=float, default=None, help="Strut radius for OBJ scenes without radii, mm.")
@click.option("--force", is_flag=True, help="Replace an existing output (never the input).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
@click.option("--max-memory", default="auto", show_default=True, metavar="SIZE",
              help="Memory budget (e.g. 4GB, 1.5GiB, none); tiles and slabs are planned to fit it. "
                   "auto: half the machine's memory.")
@click.option("--executor", type=click.Choice(["serial", "threads", "processes", "dask"]), default="serial",
              show_default=True, help="Where tiles run (serial: this process, Numba threads inside).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="With --executor dask: a running scheduler, e.g. tcp://host:8786 (default: a local cluster).")
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Pool or local cluster size (default: cores).")
@click.option("--tile", type=click.IntRange(min=1), default=None, help="Tile edge, px (default: planned).")
@click.option("--slab", type=click.IntRange(min=1), default=None,
              help="Layers traced and written per slab (default: as many as --max-memory allows).")
@click.option("--dry-run", is_flag=True, help="Print the grid, tile plan, memory and time estimates; write nothing.")
@click.option("--verbose", "-v", is_flag=True, help="Print the tile plan before slicing (on stderr).")
@config_option
def command(scene, out, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
            fmt, radius, force, quiet, contour_tol, printer, at, aa, aa_z, gamma, exposure, bottom_exposure,
            bottom_layers, max_memory, executor, scheduler, workers, tile, slab, dry_run, verbose, contours):
    """Slice SCENE into layer images: every voxel centre classified exactly."""
    from slicer import load_scene
    from slicer.executors import executor_info
    from slicer.job import check_not_input, run_slice
    from slicer.tiles import auto_budget, parse_size

    from formats.base import check_destination

    check_not_input(out, scene)
    check_destination(Path(out), force)
    budget = auto_budget() if max_memory == "auto" else parse_size(max_memory)
    executor_info(executor, workers, scheduler)     # --scheduler without dask etc.: refused now
    skel = load_scene(scene, radius=radius)
    report = (lambda text: click.echo(text, err=True)) if (verbose and not dry_run) else None
    summary = run_slice(skel, out, pixel_size=pixel_size, pixel_size_y=pixel_size_y,
                        layer_height=layer_height, bounds=bounds or None, method=method, bucket=bucket,
                        threads=threads, strict=strict, fmt=fmt, force=force, scene_name=str(scene),
                        contour_tol=contour_tol, printer=printer, at=at or None, aa=aa, aa_z=aa_z, gamma=gamma,
                        exposure=exposure, bottom_exposure=bottom_exposure, bottom_layers=bottom_layers,
                        max_memory=budget, executor=executor, workers=workers, scheduler=scheduler, tile=tile,
                        slab=slab, dry_run=dry_run, report=report, contours=contours)
    if dry_run:
        _print_dry_run(skel, scene, out, summary, executor, workers, scheduler)
        return
    if not quiet:
        click.echo(
            f"{summary['width']} x {summary['height']} px x {summary['layers']} layers -> {out} [{summary['format']}] "
            f"({method}: trace {summary['trace_seconds']:.2f} s, {summary['evaluations']:,} evaluations, "
            f"write {summary['write_seconds']:.2f} s)")
        if summary.get("estimate"):
            from formats.estimate import PrintEstimate

            click.echo(PrintEstimate.from_dict(summary["estimate"]).describe())


def _print_dry_run(skel, scene, out, summary, executor, workers, scheduler) -> None:
    """The ``--dry-run`` report: scene warnings, grid, tile plan, estimates."""
    from slicer.commands.info import scene_stats

    plan = summary["plan"]
    g = plan["grid"]
    click.echo("dry run: nothing is written")
    click.echo(f"scene:     {scene} ({skel.n_segments:,} segments)")
    click.echo(f"output:    {out} [{summary['format']}]")
    where = executor + (f" at {scheduler}" if scheduler else "") + (f", {workers} workers" if workers else "")
    click.echo(f"executor:  {where}")
    click.echo(summary["plan_text"])
    if summary.get("estimate"):
        from formats.estimate import PrintEstimate

        click.echo(f"estimate:  {PrintEstimate.from_dict(summary['estimate']).describe()} "
                   f"(the grid's layers, an upper bound; resin once sliced)")
    for w in scene_stats(skel, g["pixel_size"][0])["warnings"]:
        click.echo(f"warning:   {w['message']}")
