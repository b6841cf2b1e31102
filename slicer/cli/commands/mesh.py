"""``skelslice mesh``: the surface as a certified triangle mesh, or the skeleton as a 3MF beam lattice."""
from __future__ import annotations

import click

from slicer._kernels.runtime.launch import numba_threads
from slicer.atomic import check_destination
from slicer.errors import OutputError
from slicer.job.run import check_not_input
from slicer.job.spec import SliceJob
from slicer.meshing.beams3mf import write_beam_lattice
from slicer.meshing.output import mesh_format, write_mesh
from slicer.meshing.composite import mesh_part
from slicer.meshing.surface import DEFAULT_TOL
from slicer.parts.part import as_part
from slicer.cli.commands.options import blend_option, load_part_from, part_inputs, part_options, positive, radius_option
from slicer.cli.commands.supports import pop_support_options, supports_for, supports_options


@click.command("mesh")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", "out", required=True, type=click.Path(dir_okay=False),
              help="Mesh file: .stl, .ply, .obj or .3mf (with --beams: a .3mf beam lattice).")
@click.option("--tol", type=float, default=DEFAULT_TOL, show_default=True, callback=positive, metavar="MM",
              help="Two-sided Hausdorff distance to certify between the mesh and the surface F = 1, mm.")
@click.option("--beams", is_flag=True,
              help="Write the skeleton as a 3MF Beam Lattice (beams with their end radii, the part's clipping "
                   "and solid meshes) instead of meshing the surface.")
@click.option("--uniform", is_flag=True,
              help="Keep the uniform mesh of marching tetrahedra: equal triangles everywhere, not simplified "
                   "(by default the certified uniform mesh is simplified and certified again).")
@click.option("--tile", type=float, default=None, callback=positive, metavar="MM",
              help="Mesh in tiles about this wide, as many at once as --threads, each simplified and certified, then "
                   "united (default: tiles only when the lattice's band of cubes would not fit in memory).")
@click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores).")
@radius_option
@part_options
@blend_option
@supports_options
@click.option("--force", is_flag=True, help="Replace an existing output (never the input).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing on success.")
def command(scene, out, tol, beams, uniform, tile, threads, radius, solids, clips_inside, clips_outside, repair, blend, force,
            quiet, **support_kw):
    """Mesh SCENE's surface with a certified Hausdorff bound, or write its skeleton as a 3MF beam lattice.

    The surface mesh is closed, consistently wound and manifold: the lattice's
    surface (a supported scene's model, supports and pad united; with --blend
    union every strut's own solid; --supports auto adds supports and a pad
    first, found on a 0.05 mm grid), clipped by the part's clipping meshes and
    united with its solid meshes. The command prints the bound it certified
    (exit status 1 if it could not certify --tol).

    Example: skelslice mesh octet.json -o octet.stl --tol 0.01
    """
    check_not_input(out, *part_inputs(scene, {"solids": solids, "clips_inside": clips_inside,
                                              "clips_outside": clips_outside}))
    part = load_part_from(scene, radius, solids, clips_inside, clips_outside, repair, quiet)
    if mesh_format(out) != "3mf" and beams:
        raise OutputError(f"{out}: --beams writes a 3MF beam lattice; name the output .3mf")
    check_destination(out, force)
    with numba_threads(threads):
        part = supports_for(part, pop_support_options(support_kw), SliceJob.from_options(pixel_size=0.05), blend,
                            quiet)
    if beams:
        st = write_beam_lattice(part, out, force=force)
        if not quiet:
            extra = (f", clipped {st['clipping']}" if st["clipping"] else "") + \
                    (f", {st['solids']} solid meshes" if st["solids"] else "")
            click.echo(f"beam lattice: {st['nodes']:,} nodes, {st['beams']:,} beams{extra} -> {out}")
        return
    with numba_threads(threads):
        m = mesh_part(part, tol=tol, compact=not uniform, blend=blend, tile=tile,
                      progress=None if quiet else lambda line: click.echo(line, err=True))
    write_mesh(m.vertices, m.faces, out, force=force)
    st = m.stats
    if not quiet:
        click.echo(f"{len(m.faces):,} triangles, {len(m.vertices):,} vertices -> {out}; certified Hausdorff bound "
                   f"{m.bound:.4g} mm (mesh to surface {m.mesh_to_surface:.4g}, surface to mesh "
                   f"{m.surface_to_mesh:.4g}; tolerance {tol:g})"
                   + (f", cubes of {m.cell:.4g} mm, {st['attempts']} attempt(s)" if "attempts" in st else "")
                   + (f" (finer where struts meet: {_finer(st['finer'])})" if st.get("finer") else "")
                   + (f", in {len(st['tiles'])} tiles" if "tiles" in st else "")
                   + (f", {st['lattices']} summed lattices united" if st.get("lattices", 1) > 1 else "")
                   + (f", {st['cubes_near_meshes']:,} cubes and {st['probed_pieces']:,} triangle pieces checked "
                      f"where {_meeting(part, st)}" if "probed_pieces" in st else "")
                   + (f", simplified from {st['uniform_triangles']:,} uniform triangles"
                      if "uniform_triangles" in st else "") + f", {st['seconds']:.1f} s")
    if not m.certified:
        click.echo(f"error: the bound {m.bound:.4g} mm is above --tol {tol:g} mm after {st['attempts']} attempts; "
                   f"the mesh is written but not certified", err=True)
        raise SystemExit(1)


def _finer(levels) -> str:
    """The finer cubes of a graded uniform mesh, level by level: "890,640 of 0.04 mm, ..."."""
    return ", ".join(f"{level['cubes']:,} of {level['cube']:.4g} mm" for level in levels)


def _meeting(part, stats) -> str:
    """Where the checked pieces are: near the part's meshes, where the united lattices meet, or both."""
    united = stats.get("lattices", 1) > 1
    if as_part(part).meshes:
        return "the united lattices and the part's meshes meet" if united else "the lattice meets the part's meshes"
    return "the united lattices meet"
