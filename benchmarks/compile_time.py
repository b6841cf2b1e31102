"""Numba compile time of a job's first call, this tree against another, in one run.

Usage::

    python benchmarks/compile_time.py [--baseline TREE] [--repeat N]
                                      [--jobs contours trace render mesh mesh_part] [--kernels N] [--json out.json]

Jobs:

``contours``
    The first ``slicer.contours.plane_contours`` of the octet sample at
    z = 5 mm, 1 µm (the guaranteed contours' quadtree, walks, root solves and
    chord refinement): what the first contour output (``.cli``, ``.3mf``,
    ``--contours``, ``--aa exact``) of a fresh install waits for.
``trace``
    The first ``slicer.slice_skeleton`` of the jellyfish sample at
    0.05 mm (the README's quick start).
``render``
    The first ``slicer.render`` of the jellyfish sample at 500 x 500 (the
    README's ``render`` example).
``mesh``
    The first ``slicer.meshing.mesh_scene`` of two struts at tol 0.1 mm (the
    ball bounds, the field and the compact step's distance kernels): what the
    first ``skelslice mesh`` of a fresh install waits for.
``mesh_part``
    The first ``slicer.meshing.mesh_part`` of the same struts clipped by a
    box (the mesh job's kernels and the winding numbers): the first
    ``skelslice mesh`` of a part (a tree without ``mesh_part`` cannot run it).

Each run is a fresh subprocess with ``PYTHONPATH`` set to the tree under test
and an empty Numba cache folder of its own (``NUMBA_CACHE_DIR``), so every
kernel the job needs is compiled; it reports the first call's seconds
(``first_seconds``, compile and run), a second call's (``steady_seconds``,
the run alone) and their difference. A second subprocess then loads the
same kernels from that cache (``cached_seconds``: its first call). The
trees' packages are byte-compiled first (:func:`speed.byte_compile`). The
table shows medians of ``--repeat`` runs; the JSON (``--json``) holds every
run, the command and the machine (:mod:`validation.machine`), never a local
path.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from speed import byte_compile, trees_to_run  # noqa: E402  (as the speed benchmark does)

JOBS = ("contours", "trace", "render", "mesh", "mesh_part")


# ---------------------------------------------------------------- worker side

def _job(name: str):
    """The call a job times (imports done beforehand)."""
    from sample_lattices import load_sample
    if name == "contours":
        from slicer.contours import plane_contours
        skel = load_sample("octet_2x2x2")
        return lambda: plane_contours(skel, 5.0, 1e-3)
    if name in ("mesh", "mesh_part"):
        from slicer import Skeleton
        from slicer.meshing import mesh_scene
        strut = Skeleton([[0, 0, 0], [0, 0, 2], [1, 0, 3]], [[0, 1], [1, 2]], [[0.5, 0.5], [0.5, 0.3]])
        if name == "mesh":
            return lambda: mesh_scene(strut, tol=0.1)
        import trimesh
        from slicer.meshing import mesh_part
        from slicer.parts.meshes import make_mesh
        from slicer.parts.part import Part, PartMesh
        box = trimesh.creation.box((2, 2, 2))
        part = Part(strut, (PartMesh(make_mesh(box.vertices, box.faces, "box"), "clip-inside"),))
        return lambda: mesh_part(part, tol=0.1)
    from slicer import render, slice_skeleton      # the names both layouts have
    skel = load_sample("jellyfish")
    if name == "render":
        return lambda: render(skel, size=(500, 500))
    return lambda: slice_skeleton(skel, 0.05)


def _per_kernel(buffer) -> dict:
    """Seconds of each compiled function from Numba's compile events, its callees' compiles left out
    (they nest: a callee compiles while its caller is typed)."""
    own, stack = {}, []
    for ts, ev in buffer:
        f = ev.data["dispatcher"].py_func
        name = f"{f.__module__}.{f.__qualname__}"
        if ev.is_start:
            stack.append([name, ts, 0.0])
            continue
        name, start, inner = stack.pop()
        took = ts - start
        own[name] = own.get(name, 0.0) + took - inner
        if stack:
            stack[-1][2] += took
    return own


def worker(argv) -> int:
    """``--worker JOB``: time the job's first and second call; print JSON (with each kernel's own compile
    seconds of the first call)."""
    from numba.core import event
    t0 = time.perf_counter()
    call = _job(argv[0])
    t1 = time.perf_counter()
    rec = event.RecordingListener()
    event.register("numba:compile", rec)
    call()
    t2 = time.perf_counter()
    event.unregister("numba:compile", rec)
    call()
    t3 = time.perf_counter()
    print(json.dumps({"import_seconds": t1 - t0, "first_seconds": t2 - t1, "steady_seconds": t3 - t2,
                      "kernels": _per_kernel(rec.buffer)}))
    return 0


# ---------------------------------------------------------------- driver side

def _run(job: str, tree: Path, cache: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    env["NUMBA_CACHE_DIR"] = str(cache)
    env.pop("SKELSLICE_NUMBA_CACHE", None)
    env.pop("PYTHONSTARTUP", None)
    p = subprocess.run([sys.executable, str(HERE / "compile_time.py"), "--worker", job], cwd=cache, env=env,
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{job} on {tree.name} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def measure(trees: dict, jobs, repeat: int, log=print) -> list[dict]:
    """Every job ``repeat`` times on every tree, alternating the trees; one row per (job, tree)."""
    for tree in trees.values():
        if not byte_compile(tree):
            raise RuntimeError(f"byte-compiling {tree.name} failed")
    runs = {(job, label): [] for job in jobs for label in trees}
    for job in jobs:
        for k in range(repeat):
            for label, tree in trees.items():
                with tempfile.TemporaryDirectory(prefix="skelslice-compile-") as tmp:
                    cold = _run(job, tree, Path(tmp))
                    warm = _run(job, tree, Path(tmp))
                run = {"first_seconds": cold["first_seconds"], "steady_seconds": cold["steady_seconds"],
                       "compile_seconds": cold["first_seconds"] - cold["steady_seconds"],
                       "cached_seconds": warm["first_seconds"], "kernels": cold["kernels"]}
                runs[(job, label)].append(run)
                log(f"{job} {label} run {k + 1}: first {run['first_seconds']:.1f} s, "
                    f"steady {run['steady_seconds']:.2f} s, cached {run['cached_seconds']:.2f} s")
    rows = []
    for (job, label), rs in runs.items():
        row = {"job": job, "tree": label, "runs": rs}
        for key in ("first_seconds", "compile_seconds", "cached_seconds"):
            row["median_" + key] = statistics.median(r[key] for r in rs)
        names = {n for r in rs for n in r["kernels"]}
        row["median_kernel_seconds"] = dict(sorted(
            ((n, statistics.median(r["kernels"].get(n, 0.0) for r in rs)) for n in names), key=lambda x: -x[1]))
        rows.append(row)
    return rows


def table(rows, labels) -> str:
    """Markdown table: per job, the median compile and cache-load seconds of each tree."""
    head = ["job"] + [f"{lab} compile" for lab in labels] + [f"{lab} cached" for lab in labels]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for job in dict.fromkeys(r["job"] for r in rows):
        by = {r["tree"]: r for r in rows if r["job"] == job}
        cells = [job] + [f"{by[lab]['median_compile_seconds']:.1f} s" for lab in labels]
        cells += [f"{by[lab]['median_cached_seconds']:.2f} s" for lab in labels]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def kernel_table(rows, label: str, most: int) -> str:
    """Markdown table: per job, the kernels of tree ``label`` that take longest to compile (their own
    seconds, callees apart) and their share of the job's compile seconds."""
    lines = ["| job | kernel | seconds | share |", "|---|---|---|---|"]
    for r in rows:
        if r["tree"] != label:
            continue
        for name, sec in list(r["median_kernel_seconds"].items())[:most]:
            lines.append(f"| {r['job']} | `{name.removeprefix('slicer._kernels.')}` | {sec:.1f} s | "
                         f"{100 * sec / r['median_compile_seconds']:.0f} % |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        return worker(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="Another source tree to run (e.g. an older checkout).")
    ap.add_argument("--repeat", type=int, default=2, help="Runs per job and tree; the table shows the median.")
    ap.add_argument("--jobs", nargs="+", choices=JOBS, default=["contours"])
    ap.add_argument("--kernels", type=int, default=10, help="Kernels listed per job in the per-kernel table.")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.kernels < 0:
        ap.error("--repeat must be >= 1 and --kernels >= 0")
    trees = trees_to_run(ap, args.baseline)
    sys.path.insert(0, str(ROOT))
    from validation import machine

    rows = measure(trees, args.jobs, args.repeat, log=lambda s: print(s, file=sys.stderr))
    print(table(rows, list(trees)))
    if args.kernels:
        print()
        print(kernel_table(rows, "current", args.kernels))
    if args.json is not None:
        doc = {"benchmark": "compile_time", "command": machine.command_line("python benchmarks/compile_time.py", argv),
               "machine": machine.describe(), "repeat": args.repeat, "trees": list(trees), "rows": rows}
        machine.write_json(args.json, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
