"""Click options shared by commands, declared once.

Each decorator adds a group of options whose names are the flat option names
of :class:`slicer.job.spec.SliceJob` (``pixel_size``, ``method``, ``printer``
...), so a command turns its keyword arguments into a job with
:func:`job_from`. ``--config FILE.toml`` (:mod:`slicer.job.config`) feeds the
same options.
"""
from __future__ import annotations

import click

from slicer.model.blend import BLENDS
from slicer.tracer.buckets import DEFAULT_BUCKET
from slicer.arguments import magnitude
from slicer.errors import OptionError
from slicer.job.spec import OPTIONS, SliceJob
from slicer.parts.part import Part, load_part
from slicer.tracer.slicing import METHODS


def _stack(*decorators):
    """One decorator applying ``decorators`` in order (the first ends up first in ``--help``)."""
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f
    return apply


#: --pixel-size, --pixel-size-y, --layer-height, --bounds
grid_options = _stack(
    click.option("--pixel-size", type=float, default=None,
                 help="Pixel pitch along x (and y), mm."),
    click.option("--pixel-size-y", type=float, default=None, help="Pixel pitch along y, mm (default: --pixel-size)."),
    click.option("--layer-height", type=float, default=None, help="Layer height, mm (default: --pixel-size)."),
    click.option("--bounds", type=float, nargs=6, default=None, metavar="X0 Y0 Z0 X1 Y1 Z1",
                 help="Box to slice, mm (default: the whole surface plus one empty voxel of margin)."),
)

#: --method, --bucket, --threads, --strict, --blend
trace_options = _stack(
    click.option("--method", type=click.Choice(sorted(METHODS, key=METHODS.get)), default="interval",
                 show_default=True, help="Tracing method (sampling and segment are the paper's baselines)."),
    click.option("--bucket", type=click.IntRange(min=0), default=DEFAULT_BUCKET, show_default=True,
                 help="Bucket edge in pixels (0: one global primitive list)."),
    click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores)."),
    click.option("--strict", is_flag=True,
                 help="Do not rely on per-primitive unimodality (Lipschitz bounds only)."),
    click.option("--blend", type=click.Choice(BLENDS), default="sum", show_default=True,
                 help="How the struts' fields combine: sum (the paper's smooth blending) or union (every strut "
                      "keeps its designed radius; with --method interval or sampling)."),
)

#: --blend alone (commands without the tracing options)
blend_option = click.option("--blend", type=click.Choice(BLENDS), default="sum", show_default=True,
                            help="How the struts' fields combine: sum (the paper's) or union (the maximum).")

#: --solid, --clip-inside, --clip-outside, --repair: meshes beside the scene
part_options = _stack(
    click.option("--solid", "solids", multiple=True, type=click.Path(dir_okay=False), metavar="MESH",
                 help="Also print this mesh (STL, OBJ or PLY in mm, or 3MF), united with the scene. Repeatable."),
    click.option("--clip-inside", "clips_inside", multiple=True, type=click.Path(dir_okay=False), metavar="MESH",
                 help="Keep the lattice only inside this mesh. Repeatable (the lattice is kept inside any)."),
    click.option("--clip-outside", "clips_outside", multiple=True, type=click.Path(dir_okay=False), metavar="MESH",
                 help="Keep the lattice only outside this mesh. Repeatable."),
    click.option("--repair", is_flag=True,
                 help="Repair meshes that only need re-orienting or dropping faces with a repeated corner "
                      "(each change is reported); other defects stay errors."),
)

#: --printer, --at, --aa, --aa-z, --gamma, --exposure, --bottom-exposure, --bottom-layers
print_options = _stack(
    click.option("--printer", type=str, default=None,
                 help="Printer profile (see `skelslice printers`): pixel pitch, plate, orientation, exposure; "
                      "the model is centred on the plate, bottom at Z = 0."),
    click.option("--at", type=float, nargs=2, default=None, metavar="X Y",
                 help="With --printer: centre of the model's footprint on the plate, mm."),
    click.option("--aa", type=str, default="1", show_default=True, metavar="N|exact",
                 help="Anti-aliasing: N x N sub-pixel samples per pixel (1-16), grey = coverage; exact: grey = "
                      "the exact area of the section in the pixel, from the guaranteed contours."),
    click.option("--aa-z", is_flag=True, help="Anti-aliasing in z: exact sub-layer coverage of each voxel."),
    click.option("--gamma", type=float, default=1.0, show_default=True,
                 help="Grey = coverage^g / (coverage^g + (1 - coverage)^g); 50 % coverage is always 128."),
    click.option("--exposure", type=float, default=None, help="Normal layer exposure, s (default: printer's)."),
    click.option("--bottom-exposure", type=float, default=None,
                 help="Bottom layer exposure, s (default: printer's)."),
    click.option("--bottom-layers", type=int, default=None,
                 help="Bottom layers (Prusa: faded layers) (default: printer's)."),
)

#: --max-memory, --executor, --scheduler, --workers, --tile, --slab, --prefetch
scale_options = _stack(
    click.option("--max-memory", default="auto", show_default=True, metavar="SIZE",
                 help="Memory budget (e.g. 4GB, 1.5GiB, none); tiles and slabs are planned to fit it. "
                      "auto: half the machine's memory."),
    click.option("--executor", type=click.Choice(["serial", "threads", "processes", "dask"]), default="serial",
                 show_default=True, help="Where tiles run (serial: this process, Numba threads inside)."),
    click.option("--scheduler", default=None, metavar="ADDRESS",
                 help="With --executor dask: a running scheduler, e.g. tcp://host:8786 (default: a local cluster)."),
    click.option("--workers", type=click.IntRange(min=1), default=None,
                 help="Pool or local cluster size (default: cores)."),
    click.option("--tile", type=click.IntRange(min=1), default=None, help="Tile edge, px (default: planned)."),
    click.option("--slab", type=click.IntRange(min=1), default=None,
                 help="Layers traced and written per slab (default: as many as --max-memory allows)."),
    click.option("--prefetch/--no-prefetch", default=None,
                 help="With several slabs, trace the next slab while one is written; --prefetch sizes the "
                      "slabs so that two fit --max-memory (default: only when two planned slabs fit anyway)."),
)

#: --radius (OBJ scenes without radii)
radius_option = click.option("--radius", type=float, default=None,
                             help="Strut radius for OBJ scenes without radii, mm.")


def positive(ctx, param, value):
    """Click callback: a given value must be a finite number > 0 of at most the supported magnitude
    (:func:`slicer.arguments.magnitude`); else a usage error naming the option."""
    if value is None:
        return None
    try:
        return magnitude(value, "the value", positive=True)
    except OptionError as exc:
        text = str(exc)
        for prefix in ("the value = ", "the value "):
            text = text[len(prefix):] if text.startswith(prefix) else text
        raise click.BadParameter(text) from None


def load_part_from(scene: str, radius=None, solids=(), clips_inside=(), clips_outside=(), repair: bool = False,
                   quiet: bool = False) -> Part:
    """The part of a command's SCENE and mesh options (:func:`slicer.parts.part.load_part`);
    the reader's notes (objects left out, repairs) go to stderr unless ``quiet``."""
    meshes = ([("solid", p) for p in solids] + [("clip-inside", p) for p in clips_inside]
              + [("clip-outside", p) for p in clips_outside])
    part = load_part(scene, radius=radius, meshes=meshes, repair=repair)
    if not quiet:
        for note in part.notes:
            click.echo(f"note: {note}", err=True)
    return part


def part_inputs(scene: str, options: dict) -> list[str]:
    """SCENE and the mesh files of the part options (for refusing them as outputs)."""
    return [scene, *options.get("solids", ()), *options.get("clips_inside", ()), *options.get("clips_outside", ())]


def job_from(kwargs: dict, **extra) -> SliceJob:
    """The :class:`SliceJob` of a command's keyword arguments.

    Keys that are job options (:data:`slicer.job.spec.OPTIONS`) are taken; an
    empty ``nargs`` tuple (an option not given) counts as unset. ``extra``
    adds or overrides options.
    """
    opts = {k: (v if v != () else None) for k, v in kwargs.items() if k in OPTIONS}
    opts.update(extra)
    return SliceJob.from_options(**opts)


__all__ = ["grid_options", "trace_options", "print_options", "scale_options", "radius_option", "blend_option",
           "part_options", "positive", "job_from", "load_part_from", "part_inputs"]
