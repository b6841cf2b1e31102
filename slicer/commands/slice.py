"""``skelslice slice``: scene to layer images."""
from __future__ import annotations

import click


@click.command("slice")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(), help="Output (a folder for PNG stacks).")
@click.option("--pixel-size", required=True, type=float, help="Pixel pitch along x (and y), mm.")
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
@click.option("--radius", type=float, default=None, help="Strut radius for OBJ scenes without radii, mm.")
@click.option("--force", is_flag=True, help="Replace an existing output.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
def command(scene, out, pixel_size, pixel_size_y, layer_height, bounds, method, bucket, threads, strict,
            fmt, radius, force, quiet):
    """Slice SCENE into layer images: every voxel centre classified exactly."""
    from slicer import load_scene
    from slicer.job import run_slice

    skel = load_scene(scene, radius=radius)
    summary = run_slice(skel, out, pixel_size=pixel_size, pixel_size_y=pixel_size_y,
                        layer_height=layer_height, bounds=bounds or None, method=method, bucket=bucket,
                        threads=threads, strict=strict, fmt=fmt, force=force, scene_name=str(scene))
    if not quiet:
        click.echo(
            f"{summary['width']} x {summary['height']} px x {summary['layers']} layers -> {out} "
            f"({method}: trace {summary['trace_seconds']:.2f} s, {summary['evaluations']:,} evaluations, "
            f"write {summary['write_seconds']:.2f} s)")
