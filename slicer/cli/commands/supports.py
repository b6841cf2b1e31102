"""``skelslice supports`` and the ``--supports auto`` option of the slicing commands."""
from __future__ import annotations

from pathlib import Path

import click

from slicer.atomic import check_destination
from slicer.errors import OptionError
from slicer.job.run import check_not_input
from slicer.job.spec import SliceJob
from slicer.scene.read import load_scene
from slicer.model.skeleton import Skeleton
from slicer.supports.build import SupportSettings, supported_scene, write_supported
from slicer.supports.show import support_stats, support_voxels

#: SupportSettings fields the command line sets (option name = field name with dashes)
_SETTINGS = ("tip_radius", "elevation", "pad", "pad_thickness", "pad_margin", "pillar_radius", "head_length",
             "penetration", "bridge_length", "critical_angle", "tree_distance")


def _stack(decorators):
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f
    return apply


#: the look of the supports (shared by ``supports`` and the ``--supports auto`` commands)
support_settings_options = _stack([
    click.option("--tip-radius", type=float, default=None, metavar="MM",
                 help="Radius of each head's tip where it enters the model [default: 0.2]."),
    click.option("--elevation", type=float, default=None, metavar="MM",
                 help="Lift of the model above the pad or plate, whole layers; 0: on the pad [default: 3]."),
    click.option("--pad/--no-pad", default=None, help="A pad under the supports (and the model) [default: --pad]."),
    click.option("--pad-thickness", type=float, default=None, metavar="MM", help="Thickness of the pad [default: 1]."),
    click.option("--pad-margin", type=float, default=None, metavar="MM",
                 help="How far the pad reaches beyond the pillars [default: 2]."),
    click.option("--pillar-radius", type=float, default=None, metavar="MM",
                 help="Radius of the pillars [default: 0.5]."),
    click.option("--head-length", type=float, default=None, metavar="MM",
                 help="Length of a head, from its tip to the pillar [default: 1]."),
    click.option("--penetration", type=float, default=None, metavar="MM",
                 help="How far a tip enters the model [default: 0.2]."),
    click.option("--bridge-length", type=float, default=None, metavar="MM",
                 help="Largest span of a region or overhang left between support points [default: 2]."),
    click.option("--critical-angle", type=float, default=None, metavar="DEG",
                 help="Support overhangs flatter than this from the horizontal; 0: none [default: 45]."),
    click.option("--tree-distance", type=float, default=None, metavar="MM",
                 help="Heads within this distance share a pillar (up to 4); 0: one pillar each [default: 3]."),
])

#: ``--supports none|auto`` and the look of the supports
supports_options = _stack([
    click.option("--supports", "supports", type=click.Choice(["none", "auto"]), default="none", show_default=True,
                 help="auto: add supports and a pad to the scene before slicing (as `skelslice supports`)."),
    support_settings_options,
])


def pop_support_options(kw: dict) -> dict:
    """The support options of a command's keyword arguments (removed from ``kw``)."""
    out = {k: kw.pop(k) for k in _SETTINGS if k in kw}
    out["supports"] = kw.pop("supports", "none")
    return out


def settings_from(opts: dict, pixel_size: float, layer_height: float):
    """:class:`SupportSettings` of the command line's options on a grid's pitch."""
    given = {k: v for k, v in opts.items() if k in _SETTINGS and v is not None}
    return SupportSettings(pixel_size=pixel_size, layer_height=layer_height, **given)


def job_pitch(job) -> tuple[float, float]:
    """The pixel size and layer height a job slices at (the printer's with ``--printer``)."""
    resolved = job.resolve("")
    return float(resolved.pitch[0]), float(resolved.layer_height)


def add_supports(skel, opts: dict, job, blend: str = "sum", quiet: bool = True):
    """``skel`` with supports when ``opts["supports"] == "auto"`` (else unchanged), found on
    the job's own grid pitch; a short note on stderr unless ``quiet``.

    Raises
    ------
    OptionError
        Support settings without ``--supports auto``, or a scene that is not a lattice alone.
    """
    given = [k for k in _SETTINGS if opts.get(k) is not None]
    if opts.get("supports", "none") != "auto":
        if given:
            raise OptionError(f"--{given[0].replace('_', '-')} needs --supports auto")
        return skel
    if not isinstance(skel, Skeleton):
        raise OptionError("--supports auto needs a lattice alone (a scene without meshes)")
    px, h = job_pitch(job)
    out, rep = supported_scene(skel, settings_from(opts, px, h), blend=blend, threads=job.trace.threads)
    if not quiet:
        click.echo(f"supports: {describe(out, rep)}", err=True)
    return out


def supports_for(part, opts: dict, job, blend: str = "sum", quiet: bool = True):
    """``part`` (a :class:`~slicer.parts.part.Part`) with supports when ``opts`` ask for them
    (:func:`add_supports`, on the job's grid pitch), else ``part`` itself.

    Raises
    ------
    OptionError
        As :func:`add_supports`.
    """
    if opts.get("supports", "none") != "auto" and all(v is None for k, v in opts.items() if k != "supports"):
        return part
    return add_supports(part.skeleton if not part.has_meshes else part, opts, job, blend, quiet)


def support_report(skel, result) -> dict | None:
    """The check report's ``supports`` entry of a supported scene (None otherwise): the
    counts of :func:`slicer.supports.show.support_stats`, the voxels and resin the
    supports add to the job, and a ``line`` for people."""
    st = support_stats(skel)
    if st is None:
        return None
    vox = support_voxels(skel, result) or {}
    st.update(vox)
    resin = f"resin {vox['resin_ml']:.3g} ml" if vox else f"resin about {st['resin_ml_estimate']:.3g} ml"
    st["line"] = (f"supports: {st['heads']} heads, {st['support_struts']} support and {st['pad_struts']} pad struts; "
                  f"{resin} of the job's")
    return st


def describe(skel, rep) -> str:
    """One line: what the supports are."""
    left = "" if rep.islands_left == 0 else (
        f"; {rep.islands_left} islands left after {rep.rounds} rounds" if rep.islands_left > 0
        else "; the last round's additions were not re-checked")
    return (f"{rep.supports} supports ({rep.to_model} onto the model) on {rep.pillars} pillars "
            f"({rep.trees} shared, {rep.braces} braces), {rep.pad_rows} pad rows, "
            f"{skel.support_segments} struts; model lifted {rep.lift:g} mm ({rep.seconds:.1f} s){left}")


@click.command("supports")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="The supported scene (.json, format version 2 with groups).")
@click.option("--printer", type=str, default=None,
              help="Find the support points on this printer's pixel pitch and layer height.")
@click.option("--pixel-size", type=float, default=None, help="Pixel pitch the points are found on, mm [default: 0.05].")
@click.option("--layer-height", type=float, default=None, help="Layer height, mm [default: the pixel size].")
@support_settings_options
@click.option("--blend", type=click.Choice(["sum", "union"]), default="sum", show_default=True,
              help="The model's blend (as it will be sliced).")
@click.option("--radius", type=float, default=None, help="Strut radius for OBJ scenes without radii, mm.")
@click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores).")
@click.option("--force", is_flag=True, help="Replace an existing output (never the input).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
def command(scene, out, printer, pixel_size, layer_height, blend, radius, threads, force, quiet, **opts):
    """Add supports and a pad to SCENE: support points at every island, local
    minimum and long span the check would find, a tapered head and a pillar
    from each down to the pad, the plate or the model below. OUT holds the
    model's struts first, in order, lifted by --elevation, then the supports
    and the pad, marked as groups that unite with the model.
    """
    check_not_input(out, scene)
    if Path(out).suffix.lower() != ".json":
        raise OptionError(f"{out}: a supported scene is written as .json (format version 2 with groups)")
    check_destination(Path(out), force)
    if pixel_size is None and printer is None:
        pixel_size = 0.05
    job = SliceJob.from_options(printer=printer, pixel_size=pixel_size, layer_height=layer_height)
    px, h = job_pitch(job)
    st = settings_from(opts, px, h)
    skel = load_scene(scene, radius=radius)
    sup, rep = supported_scene(skel, st, blend=blend, threads=threads)
    write_supported(sup, out, force=force)
    if not quiet:
        click.echo(f"{scene}: {describe(sup, rep)} -> {out}")


__all__ = ["command", "supports_options", "support_settings_options", "pop_support_options", "add_supports",
           "supports_for",
           "support_report",
           "settings_from", "job_pitch", "describe"]
