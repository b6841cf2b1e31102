"""Certified meshes of parts: what the part's meshes cost over the lattice's mesh alone.

Usage::

    python benchmarks/mesh_parts_bench.py [--repeat N] [--json out.json]

Parts of the sample cubic_2x2x2 (10 mm, struts of 0.5 mm radius) at ``--tol 0.05``:

* ``sphere clip``: kept inside a polyhedral sphere (icosphere, 1,280 faces) of radius 4.5 mm;
* ``plate``: united with a solid plate 12 x 12 x 1 mm under it, overlapping the bottom nodes;
* ``hole``: a square hole (clip-outside box 3 x 3 x 14 mm) through its middle.

With ``--supported``, also cubic_2x2x2 with the supports and pad ``skelslice supports`` adds
(default settings, a 0.05 mm grid) at ``--tol 0.2``, uniform (``--uniform``) and compact.

Each row is one method in the same run: ``lattice`` is ``mesh_scene`` of the lattice alone
(the work a part cannot skip), ``part`` is ``mesh_part`` (the lattice's mesh, the booleans and
the part's certificate, then the simplification). Seconds are medians of ``--repeat`` runs
(the first run of each method also compiles nothing: the kernels are warmed first).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np
import trimesh

from sample_lattices import load_sample
from slicer.meshing import mesh_part, mesh_scene
from slicer.parts.meshes import make_mesh
from slicer.parts.part import Part, PartMesh
from slicer.supports.build import SupportSettings, supported_scene
from validation import machine

TOL = 0.05
#: the supported scene's tolerance
SUPPORTED_TOL = 0.2


def _mesh(m, name):
    return make_mesh(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), name)


def parts():
    skel = load_sample("cubic_2x2x2")
    lo, hi = skel.support_bounds()
    mid = 0.5 * (lo + hi)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=4.5)
    sphere.apply_translation(mid)
    plate = trimesh.creation.box((12, 12, 1))
    plate.apply_translation([mid[0], mid[1], lo[2] + 0.6])
    hole = trimesh.creation.box((3, 3, 14))
    hole.apply_translation(mid)
    return skel, [("sphere clip", (PartMesh(_mesh(sphere, "sphere"), "clip-inside"),)),
                  ("plate", (PartMesh(_mesh(plate, "plate"), "solid"),)),
                  ("hole", (PartMesh(_mesh(hole, "hole"), "clip-outside"),))]


def _timed(fn, repeat):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def _row(part, method, m, sec):
    t = m.trimesh()
    return {"part": part, "method": method, "triangles": int(len(m.faces)), "seconds": round(sec, 2),
            "bound": m.bound, "certified": m.certified, "watertight": bool(t.is_watertight),
            "rounds": m.stats.get("rounds"), "lattices": m.stats.get("lattices"),
            "cubes_near_meshes": m.stats.get("cubes_near_meshes"), "probed_pieces": m.stats.get("probed_pieces"),
            "uniform_triangles": m.stats.get("uniform_triangles")}


def run(repeat, supported=False):
    skel, cases = parts()
    mesh_scene(skel.__class__([[0, 0, 0], [0, 0, 2]], [[0, 1]], [[0.5, 0.5]]), tol=0.1)      # warm the kernels
    rows = []
    m, sec = _timed(lambda: mesh_scene(skel, tol=TOL), repeat)
    rows.append({"part": "-", "method": "lattice", "triangles": int(len(m.faces)), "seconds": round(sec, 2),
                 "bound": m.bound})
    print(rows[-1], file=sys.stderr, flush=True)
    for name, meshes in cases:
        m, sec = _timed(lambda: mesh_part(Part(skel, meshes), tol=TOL), repeat)
        rows.append(_row(name, "part", m, sec))
        print(rows[-1], file=sys.stderr, flush=True)
    if supported:
        scene, _ = supported_scene(skel, SupportSettings(pixel_size=0.05, layer_height=0.05))
        for method, compact in (("supported, uniform", False), ("supported", True)):
            m, sec = _timed(lambda: mesh_part(scene, tol=SUPPORTED_TOL, compact=compact), repeat)
            rows.append(_row(f"supports and pad (tol {SUPPORTED_TOL:g})", method, m, sec))
            print(rows[-1], file=sys.stderr, flush=True)
    return rows


def table(rows):
    lines = ["| part | method | triangles | seconds | certified bound (mm) | cubes near meshes | pieces probed |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['part']} | {r['method']} | {r['triangles']:,} | {r['seconds']} | {r['bound']:.4g} | "
                     f"{r.get('cubes_near_meshes') or '-'} | {r.get('probed_pieces') or '-'} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=1, help="Runs per method (the median is reported).")
    ap.add_argument("--json", default=None, help="Also write the rows, command and machine here.")
    ap.add_argument("--supported", action="store_true", help="Also the supported cubic_2x2x2 (about 8 minutes).")
    a = ap.parse_args(argv)
    rows = run(a.repeat, a.supported)
    res = {"benchmark": "mesh_parts_bench", "tol": TOL,
           "command": machine.command_line("python benchmarks/mesh_parts_bench.py", argv),
           "machine": machine.describe(), "rows": rows}
    machine.publish(res, table(rows), a.json)


if __name__ == "__main__":
    sys.exit(main())
