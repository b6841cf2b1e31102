"""The certified surface mesh against a uniform level set, at equal measured error.

Usage::

    python benchmarks/mesh_bench.py [--quick] [--json out.json]

For each scene, ``slicer.meshing.mesh_scene`` at ``--tol`` (triangles, seconds, the
certified bound; the compact mesh, and the certified uniform mesh it was simplified from),
then the validation mesher ``validation.reference_mesh`` (uniform marching tetrahedra,
vertices bisected onto the surface: the uniform level set the issue names) at grid edges of
1.5, 2.5, 4 and 8 times the certified mesh's cube side (the uniform mesher samples its
whole box, so finer grids cost minutes). Every mesh's error is
measured the same way, independently of how it was made: at two random points of every
triangle and its centroid, the first-order distance ``|F − 1| / ‖∇F‖`` to the surface
(mesh to surface; the largest over the points). The second table gives, per scene, the
triangles of a uniform mesh at the certified mesh's measured error (log-log fit of the
uniform runs) and of the coarsest uniform mesh whose measured error is within the certified
bound, each as a ratio.

Scenes: three tapered struts and a needle (0.6 -> 0.08 mm) at tol 0.02 mm and the sample
cubic_2x2x2 at 0.05 mm. ``--dense`` adds the dense lattice octet_2x2x2 (240 struts) and the
microstructure sample (2,976 struts, 27 mm) at 0.1 mm, compact meshes only (the uniform mesh
they come from is in their rows) and level sets at 4, 8 and 16 times their finest cube (those
on grids of more than 20 million points skipped): they take minutes each. ``--quick``: the first two only. The JSON rows of the certified meshes also say
whether each is watertight and consistently wound (trimesh), and the process's peak resident
memory so far (``peak_rss_gb``: the meshing's own for the first row of a run).
"""
from __future__ import annotations

import argparse
import resource
import sys
import time

import numpy as np
import trimesh

from sample_lattices import load_sample
from slicer import Skeleton
from slicer.errors import OptionError
from slicer.model.field import evaluate
from slicer.meshing import mesh_scene
from validation import machine
from validation.reference_mesh import reference_mesh


def measured_error(skel, vertices, faces, seed=0):
    """Largest ``|F − 1| / ‖∇F‖`` at two random points of each triangle and at its centroid, mm."""
    rng = np.random.default_rng(seed)
    tri = vertices[faces]
    w = rng.dirichlet([1.0, 1.0, 1.0], size=(len(faces), 2))
    p = np.vstack([np.einsum("tkj,tjd->tkd", w, tri).reshape(-1, 3), tri.mean(axis=1)])
    f, g = evaluate(skel, p, gradient=True)
    return float((np.abs(f - 1.0) / np.linalg.norm(g, axis=1)).max())


def closed(m):
    """Whether the mesh is watertight and consistently wound (trimesh's checks)."""
    t = trimesh.Trimesh(m.vertices, m.faces, process=False)
    return {"watertight": bool(t.is_watertight), "winding_consistent": bool(t.is_winding_consistent)}


def scenes(quick, dense=False):
    out = [("3 struts", Skeleton([[0, 0, 0], [3, 0, 0], [3, 3, 1], [0, 3, 2]], [[0, 1], [1, 2], [2, 3]],
                                 [[0.5, 0.3], [0.3, 0.45], [0.45, 0.6]]), 0.02),
           ("needle", Skeleton([[0, 0, 0], [0, 0, 3]], [[0, 1]], [[0.6, 0.08]]), 0.02)]
    if not quick:
        out += [("cubic_2x2x2", load_sample("cubic_2x2x2"), 0.05)]
    if dense:
        out += [("octet_2x2x2", load_sample("octet_2x2x2"), 0.1), ("microstructure", load_sample("microstructure"), 0.1)]
    return out


#: scenes meshed compact only, with coarse level sets (their uniform certified mesh is in the compact row)
LARGE = ("octet_2x2x2", "microstructure")
#: level sets on grids of more points are skipped (the microstructure's at 4 times its finest cube:
#: 60 million points, and memory beyond 23 GB)
MAX_LEVEL_SET_POINTS = 2e7


def run(quick, dense=False, only=None):
    rows = []
    for name, skel, tol in scenes(quick, dense):
        if only is not None and name != only:
            continue
        large = name in LARGE
        for method, compact in ((("certified uniform", False),) if not large else ()) + (("certified", True),):
            t0 = time.perf_counter()
            try:
                m = mesh_scene(skel, tol=tol, compact=compact,
                               progress=lambda line: print(f"{name}: {line}", file=sys.stderr, flush=True))
            except OptionError as err:      # beyond the band's memory limit: the refusal is the result
                rows.append({"scene": name, "method": "refused", "tol": tol, "seconds": round(time.perf_counter() - t0, 2),
                             "message": str(err)})
                print(rows[-1], file=sys.stderr, flush=True)
                m = None
                break
            secs = time.perf_counter() - t0
            ours = {"scene": name, "method": method, "tol": tol, "cell": m.cell, "triangles": int(len(m.faces)),
                    "seconds": round(secs, 2), "bound": m.bound,
                    "measured": measured_error(skel, m.vertices, m.faces),
                    "attempts": m.stats["attempts"], "band_cubes": m.stats["band_cubes"],
                    "uniform_triangles": m.stats.get("uniform_triangles", int(len(m.faces))),
                    "finer_cubes": sum(level["cubes"] for level in m.stats.get("finer", [])),
                    "tiles": len(m.stats.get("tiles", ())), **closed(m),
                    "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6}
            rows.append(ours)
            print(ours, file=sys.stderr, flush=True)
        # level sets from the finest cube side used (a graded mesh's finer cubes)
        finest = None if m is None else min([m.cell] + [level["cube"] for level in m.stats.get("finer", [])])
        for k in () if m is None else (4.0, 8.0, 16.0) if large else (1.5, 2.5, 4.0, 8.0):
            lo, hi = skel.support_bounds()
            points = float(np.prod(np.ceil((hi - lo) / (finest * k)) + 3))
            if points > MAX_LEVEL_SET_POINTS:       # its grid and triangles would not fit in memory
                print(f"{name}: level set at {finest * k:.4g} mm skipped ({points:.3g} grid points)",
                      file=sys.stderr, flush=True)
                continue
            t0 = time.perf_counter()
            man, info = reference_mesh(skel, finest * k, with_error=False)
            secs = time.perf_counter() - t0
            mesh = man.to_mesh64()
            v, f = np.asarray(mesh.vert_properties)[:, :3].astype(np.float64), np.asarray(mesh.tri_verts)
            rows.append({"scene": name, "method": "uniform", "tol": None, "cell": finest * k,
                         "triangles": int(len(f)), "seconds": round(secs, 2), "bound": None,
                         "measured": measured_error(skel, v, f)})
            print(rows[-1], file=sys.stderr, flush=True)
    return rows


def table(rows):
    lines = ["| scene | method | cube / edge (mm) | triangles | seconds | certified bound (mm) | measured error (mm) "
             "| uniform triangles (attempts) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["method"] == "refused":
            lines.append(f"| {r['scene']} (tol {r['tol']:g}) | refused after {r['seconds']:.1f} s: {r['message']} |"
                         " | | | | | |")
            continue
        bound = f"{r['bound']:.4g}" if r["bound"] is not None else "-"
        made = f"{r['uniform_triangles']:,} ({r['attempts']})" if "attempts" in r else "-"
        lines.append(f"| {r['scene']} | {r['method']} | {r['cell']:.4g} | {r['triangles']:,} | {r['seconds']:.1f} | "
                     f"{bound} | {r['measured']:.3g} | {made} |")
    lines += ["", "| scene, mesh | certified: triangles | uniform at its measured error | ratio | uniform measuring at most "
              "its certified bound | ratio |", "|---|---|---|---|---|---|"]
    for name, method in dict.fromkeys((r["scene"], r["method"]) for r in rows if r["method"] not in ("uniform", "refused")):
        ours = next(r for r in rows if r["scene"] == name and r["method"] == method)
        uni = sorted((r for r in rows if r["scene"] == name and r["method"] == "uniform"), key=lambda r: r["measured"])
        equal = _interpolated(uni, ours["measured"])
        within = [r for r in uni if r["measured"] <= ours["bound"]]
        coarse = min(within, key=lambda r: r["triangles"]) if within else None
        lines.append(f"| {name}, {method} | {ours['triangles']:,} | {equal:,.0f} | {ours['triangles'] / equal:.2f} | "
                     + (f"{coarse['triangles']:,} (measured {coarse['measured']:.3g} mm) | "
                        f"{ours['triangles'] / coarse['triangles']:.1f} |" if coarse else "- | - |"))
    return "\n".join(lines)


def _interpolated(uni, error):
    """Triangles of a uniform mesh measuring ``error``: log-log interpolation (or
    extrapolation) of triangles against measured error over the uniform runs."""
    x = np.log([r["measured"] for r in uni])
    y = np.log([r["triangles"] for r in uni])
    slope, icpt = np.polyfit(x, y, 1)
    return float(np.exp(icpt + slope * np.log(error)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="The two small scenes only.")
    ap.add_argument("--dense", action="store_true",
                    help="Add the dense lattice octet_2x2x2 and the microstructure sample (minutes each).")
    ap.add_argument("--only", default=None, metavar="SCENE", help="This scene alone (a name of the table's).")
    ap.add_argument("--json", default=None, help="Also write the rows, command and machine here.")
    a = ap.parse_args(argv)
    rows = run(a.quick, a.dense, a.only)
    res = {"benchmark": "mesh_bench", "command": machine.command_line("python benchmarks/mesh_bench.py", argv),
           "machine": machine.describe(), "rows": rows}
    machine.publish(res, table(rows), a.json)


if __name__ == "__main__":
    sys.exit(main())
