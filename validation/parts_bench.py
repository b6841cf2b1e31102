"""What the meshes cost in a part's job: an implant-like part on a printer plate.

The part is made here (no data file): a spinal-cage-like solid -- a rounded
38 x 10 mm ring 25 mm tall with two 14 x 6 mm windows, meshed by manifold3d
and refined to 5,440 faces -- and a cubic lattice of 1.05 mm cells with
0.25 mm struts filling both windows (10,968 beams), like the 3MF
Consortium's "spinal implant" sample (5,672 faces, 11,821 beams). The job is
the full ``skelslice slice`` job (:func:`slicer.job.run.run_slice`) onto a
printer's plate (default: Prusa SL1S, 0.05 mm pixels and layers).

Reported per run: the job's CPU time (all threads of this process), the CPU
time of the mesh work (cutting every mesh at every layer, combining the runs
with the lattice's: it runs in the calling thread, measured with
``time.thread_time``) and its share of the job; wall times are shown for
orientation only (they depend on the machine's load). ``repeat`` keeps the
run with the least job CPU time.

Run: ``skelslice bench parts [--quick] [--repeat N] [--json FILE]`` or
``python -m validation.parts_bench``. Instruction counts, which do not depend
on the machine's load (``Ir`` in the last line callgrind prints)::

    valgrind --tool=callgrind --callgrind-out-file=all.out python -m validation.parts_bench --scale 0.5
    valgrind --tool=callgrind --instr-atstart=no --callgrind-out-file=mesh.out \
        python -m validation.parts_bench --scale 0.5 --callgrind-meshes
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import manifold3d
import numpy as np

from slicer.parts import slicing as part_slicing
from slicer.atomic import write_bytes
from slicer.job.run import run_slice
from slicer.scene.lattice import generate_lattice
from slicer.parts.meshes import make_mesh
from slicer.parts.part import Part, PartMesh
from slicer.model.skeleton import Skeleton


def implant_like(scale: float = 1.0) -> Part:
    """The benchmark part; ``scale`` shrinks every length (and the cell) for a quick run."""
    outer = manifold3d.CrossSection.square((34 * scale, 6 * scale), center=True).offset(
        2.0 * scale, manifold3d.JoinType.Round, circular_segments=24)
    window = manifold3d.CrossSection.square((12 * scale, 4 * scale), center=True).offset(
        1.0 * scale, manifold3d.JoinType.Round, circular_segments=24)
    cs = outer - window.translate((8.5 * scale, 0.0)) - window.translate((-8.5 * scale, 0.0))
    cage = manifold3d.Manifold.extrude(cs, 25.0 * scale).refine(4).to_mesh64()
    mesh = make_mesh(np.asarray(cage.vert_properties)[:, :3], np.asarray(cage.tri_verts).astype(np.int64), "cage")
    parts = []
    cell = 1.05
    for cx in (-8.5, 8.5):            # 13 x 5 x 23 cells centred in each window
        parts.append(generate_lattice("cubic", (13, 5, 23), cell * scale, 0.25 * scale,
                                      origin=((cx - 6.5 * cell) * scale, -2.5 * cell * scale, 0.45 * scale)))
    nodes = np.concatenate([p.nodes for p in parts])
    segs = np.concatenate([parts[0].segments, parts[1].segments + parts[0].n_nodes])
    radii = np.concatenate([p.radii for p in parts])
    return Part(Skeleton(nodes, segs, radii), [PartMesh(mesh, "solid")])


def run(scale: float = 1.0, printer: str = "prusa-sl1s", threads: int | None = None, repeat: int = 1) -> dict:
    """Slice the part onto ``printer``'s plate; returns the measurements (see the module docstring)."""
    part = implant_like(scale)
    best = None
    for _ in range(max(1, int(repeat))):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "part.sl1s"
            w0, c0 = time.perf_counter(), time.process_time()
            s = run_slice(part, out, printer=printer, threads=threads, progress=False)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        row = {"job_cpu_s": cpu, "job_wall_s": wall, "mesh_cpu_s": s["mesh_cpu_seconds"],
               "mesh_wall_s": s["mesh_seconds"], "trace_wall_s": s["trace_seconds"], "write_wall_s": s["write_seconds"],
               "mesh_share": s["mesh_cpu_seconds"] / cpu}
        if best is None or cpu < best["job_cpu_s"]:
            best = row
    return {"part": part.describe(), "scale": scale, "printer": printer, "faces": part.solids()[0].n_faces,
            "beams": part.skeleton.n_segments, "layers": s["layers"], "plate": [s["width"], s["height"]],
            "evaluations": s["evaluations"], "threads": s["threads"], **best}


def format_table(r: dict) -> str:
    return "\n".join([
        f"part:      {r['part']} (scale {r['scale']:g})",
        f"job:       {r['printer']}, {r['plate'][0]} x {r['plate'][1]} px x {r['layers']} layers, "
        f"{r['evaluations']:,} evaluations, {r['threads']} threads",
        f"{'':11}{'CPU s':>9}{'wall s':>9}",
        f"{'job':<11}{r['job_cpu_s']:>9.2f}{r['job_wall_s']:>9.2f}",
        f"{'meshes':<11}{r['mesh_cpu_s']:>9.2f}{r['mesh_wall_s']:>9.2f}   "
        f"({100 * r['mesh_share']:.1f} % of the job's CPU time)",
        f"{'trace':<11}{'':>9}{r['trace_wall_s']:>9.2f}",
        f"{'write':<11}{'':>9}{r['write_wall_s']:>9.2f}",
    ])


def instrument_meshes_only() -> None:
    """Under ``valgrind --tool=callgrind --instr-atstart=no``: switch callgrind's
    instrumentation on for the mesh work only (with ``callgrind_control``), so the
    instruction count is that of cutting the meshes and combining the runs. Run the job
    a second time under callgrind with instrumentation from the start for the total."""
    inner = part_slicing._slice_meshes

    @functools.wraps(inner)
    def counted(*args, **kw):
        subprocess.run(["callgrind_control", "-i", "on", str(os.getpid())], check=True, capture_output=True)
        try:
            return inner(*args, **kw)
        finally:
            subprocess.run(["callgrind_control", "-i", "off", str(os.getpid())], check=True, capture_output=True)

    part_slicing._slice_meshes = counted


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--printer", default="prusa-sl1s")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--json", default=None)
    ap.add_argument("--callgrind-meshes", action="store_true",
                    help="Under callgrind --instr-atstart=no: count the mesh work's instructions only.")
    a = ap.parse_args(argv)
    if a.callgrind_meshes:
        instrument_meshes_only()
    r = run(a.scale, a.printer, a.threads, a.repeat)
    print(format_table(r))
    if a.json:
        write_bytes(a.json, (json.dumps(r, indent=1) + "\n").encode(), force=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
