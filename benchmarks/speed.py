"""Speed of the dense-lattice jobs, this tree against another (e.g. release 0.1.0), in one run.

Usage::

    python benchmarks/speed.py [--baseline TREE] [--repeat N] [--threads T] [--quick]
                               [--jobs octet micro ...] [--json out.json]

Jobs (full size; ``--quick`` shrinks every one to a smoke test of a few seconds):

``octet``
    A 10 mm octet lattice, 5 x 5 x 5 cells of 2 mm, strut radius graded
    0.12 -> 0.3 mm along z, sliced at 513 x 513 px x 1008 layers to a PNG
    stack by the ``slice`` command: the whole process (start-up, scene, trace,
    writing) timed from outside; the command's own report gives the trace
    and write seconds and the primitive evaluations.
``png``
    The writing share of the ``octet`` job (1008 PNG layers of 513 x 513), as
    the ``slice`` command reports it.
``micro``, ``jelly``, ``jelly2x``
    Trace only (``slicer.tracer.slicing.trace``): the sample microstructure at
    512 x 512 x 1024, the jellyfish at 512 x 512 x 1024 and x 2048; the
    ``trace_seconds`` the result reports, after a trace of a coarse grid in
    the same process that loads the kernels (``setup_seconds``).
``render_micro``, ``render_jelly``
    ``slicer.render.rendering.render`` of the samples at 700 x 700, iso view, timed
    after an 8 x 8 render in the same process that pays Numba's one-time
    set-up and the kernels' load (``setup_seconds`` in the JSON), as
    ``render_bench.py`` does.
``ctb``
    The jellyfish sliced for an Elegoo Saturn 3 Ultra (11520 x 5120 px) into a
    Chitubox CTB file by the ``slice`` command: the whole process, as
    ``octet``; printer-format writing at a real plate's size.

Every job runs in a fresh subprocess with ``PYTHONPATH`` set to the tree
under test and a neutral working folder, so ``--baseline`` compares two
checkouts on the same machine in the same run. Before timing, each tree's
packages are byte-compiled (as ``pip install`` does, so that no run pays
compiling Python sources, even where ``PYTHONDONTWRITEBYTECODE`` is set) and one
small job per tree loads (or compiles) its Numba kernels. The table shows the median of
``--repeat`` runs; the JSON (``--json``) holds every run, the command and the
machine (:mod:`validation.machine`), never a local path.
"""
from __future__ import annotations

import argparse
import compileall
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

# job -> (full size, quick size); sizes are (pixels, layers) or (octet cells, pixels, layers)
SIZES = {
    "octet": ((5, 513, 1008), (1, 48, 40)),
    "micro": ((512, 1024), (48, 48)),
    "jelly": ((512, 1024), (48, 48)),
    "jelly2x": ((512, 2048), (48, 96)),
    "render_micro": ((700,), (40,)),
    "render_jelly": ((700,), (40,)),
    "ctb": (("elegoo-saturn-3-ultra",), ("elegoo-saturn",)),
}
JOBS = ("octet", "png", "micro", "jelly", "jelly2x", "render_micro", "render_jelly", "ctb")
SAMPLE = {"micro": "microstructure", "jelly": "jellyfish", "jelly2x": "jellyfish",
          "render_micro": "microstructure", "render_jelly": "jellyfish"}


# ---------------------------------------------------------------- worker side
# (runs with PYTHONPATH = the tree under test: only APIs that 0.1.0 already had)

def _square_bounds(skel, pixels: int):
    lo, hi = skel.support_bounds()
    cx, cy = 0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])
    half = 0.5 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    return (cx - half, cy - half, float(lo[2]), cx + half, cy + half, float(hi[2])), 2 * half / pixels


def _worker_trace(name: str, pixels: int, layers: int, threads: int) -> dict:
    from sample_lattices import load_sample
    from slicer.grid import make_grid          # the flat paths: both layouts import them (slicer._aliases)
    from slicer.slicing import trace

    skel = load_sample(SAMPLE[name])
    bounds, px = _square_bounds(skel, pixels)
    grid = make_grid(skel.support_bounds(), px, layer_height=(bounds[5] - bounds[2]) / layers, bounds=bounds)
    # the kernels' load in this process, paid by a coarse grid first (as the render jobs)
    t0 = time.perf_counter()
    trace(skel, make_grid(skel.support_bounds(), 2 * (bounds[3] - bounds[0]) / 16), threads=threads)
    setup = time.perf_counter() - t0
    res = trace(skel, grid, threads=threads)
    return {"seconds": res.stats["trace_seconds"], "evaluations": res.stats["evaluations"],
            "runs": res.n_runs, "grid": [grid.width, grid.height, grid.layers], "setup_seconds": setup}


def _render_function():
    """``render`` of the tree under test (``slicer.rendering``, an alias of ``slicer.render.rendering`` in
    the folders' layout; ``slicer.render`` in 0.1.0)."""
    import importlib

    try:
        return importlib.import_module("slicer.rendering").render
    except ModuleNotFoundError:
        return importlib.import_module("slicer.render").render


def _worker_render(name: str, size: int, threads: int) -> dict:
    from sample_lattices import load_sample

    render = _render_function()

    skel = load_sample(SAMPLE[name])
    # Numba's one-time set-up in this process and the kernels' load, paid by a tiny image first
    # (as render_bench.py; the trace jobs time the trace alone too)
    t0 = time.perf_counter()
    render(skel, size=(8, 8), view="iso", threads=threads)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = render(skel, size=(size, size), view="iso", threads=threads)
    return {"seconds": time.perf_counter() - t0, "evaluations": int(res.stats["evaluations"]),
            "setup_seconds": setup}


def _worker_warm(threads: int) -> dict:
    from sample_lattices import load_sample
    from slicer.grid import make_grid          # the flat paths: both layouts import them (slicer._aliases)
    from slicer.slicing import trace

    render = _render_function()
    t0 = time.perf_counter()
    skel = load_sample("cubic_2x2x2")
    trace(skel, make_grid(skel.support_bounds(), 0.5), threads=threads)
    render(skel, size=(8, 8), threads=threads)
    return {"seconds": time.perf_counter() - t0}


def worker(argv) -> int:
    """``speed.py --worker JOB ARGS...``: run one job in this process, print JSON."""
    job, *args = argv
    threads = int(args[-1])
    if job == "warm":
        out = _worker_warm(threads)
    elif job.startswith("render"):
        out = _worker_render(job, int(args[0]), threads)
    else:
        out = _worker_trace(job, int(args[0]), int(args[1]), threads)
    print(json.dumps(out))
    return 0


# ---------------------------------------------------------------- driver side

def _env(tree: Path, threads: int) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    env["NUMBA_NUM_THREADS"] = str(max(threads, int(env.get("NUMBA_NUM_THREADS", "0") or 0), 1))
    env.pop("PYTHONSTARTUP", None)
    return env


def _run(cmd, tree: Path, threads: int, cwd: Path) -> tuple[float, str]:
    cmd = [str(c) for c in cmd]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, env=_env(tree, threads), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n{p.stderr[-3000:]}")
    return wall, p.stdout


def _worker_cmd(job, *args):
    return [sys.executable, str(HERE / "speed.py"), "--worker", job, *map(str, args)]


_SLICE_LINE = re.compile(r"trace ([\d.]+) s, ([\d,]+) evaluations, write ([\d.]+) s")


def octet_box(cells: int, pixels: int, layers: int):
    """``(lo, hi, pixel_size, layer_height)`` of the octet job: the cube ``[lo, hi]``
    (mm) holding the lattice's support, cut into exactly ``pixels`` and ``layers``."""
    lo, hi = -0.6, 2.0 * cells + 0.6          # the support box: sigma (2) x the top radius (0.3)
    # a hair under (hi - lo) / n, so that ceil() gives exactly n pixels (layers)
    return lo, hi, (hi - lo) / (pixels - 1e-3), (hi - lo) / (layers - 1e-3)


def _octet(tree: Path, size, threads: int, work: Path) -> dict:
    """One whole-process run of the octet slice job; the lattice is generated by the tree's own CLI."""
    cells, pixels, layers = size
    scene = work / "octet.json"
    if not scene.exists():
        _run([sys.executable, "-m", "slicer", "lattice", "octet", "--cells", cells, cells, cells,
              "--cell-size", "2", "--radius", "0.12:0.3", "-o", scene.name], tree, threads, work)
    lo, hi, px, h = octet_box(cells, pixels, layers)
    out = work / "octet_out"
    wall, text = _run([sys.executable, "-m", "slicer", "slice", scene.name, "-o", out.name, "--force",
                       "--pixel-size", repr(px), "--layer-height", repr(h), "--threads", threads,
                       "--bounds", lo, lo, lo, hi, hi, hi], tree, threads, work)
    m = _SLICE_LINE.search(text)
    if m is None:
        raise RuntimeError(f"unexpected slice output: {text!r}")
    n_files = len(list(out.glob("*.png")))
    return {"seconds": wall, "trace_seconds": float(m.group(1)), "evaluations": int(m.group(2).replace(",", "")),
            "write_seconds": float(m.group(3)), "layers_written": n_files}


def _printer_file(tree: Path, size, threads: int, work: Path) -> dict:
    """One whole-process run of the jellyfish sliced into a CTB file for printer ``size[0]``."""
    out = work / "jellyfish.ctb"
    wall, text = _run([sys.executable, "-m", "slicer", "slice", tree / "sample_lattices" / "jellyfish.json",
                       "-o", out.name, "--printer", size[0], "--force", "--threads", threads], tree, threads, work)
    m = _SLICE_LINE.search(text)
    if m is None:
        raise RuntimeError(f"unexpected slice output: {text!r}")
    return {"seconds": wall, "trace_seconds": float(m.group(1)), "evaluations": int(m.group(2).replace(",", "")),
            "write_seconds": float(m.group(3)), "bytes": out.stat().st_size}


#: the packages of a tree that the jobs import
PACKAGES = ("slicer", "formats", "validation", "sample_lattices")


def byte_compile(tree: Path) -> bool:
    """Write the bytecode of ``tree``'s packages beside their sources (``__pycache__``),
    as ``pip install`` does for an installed package; True when every file compiled."""
    ok = True
    for pkg in PACKAGES:
        if (tree / pkg).is_dir():
            ok = compileall.compile_dir(str(tree / pkg), quiet=1, workers=1) and ok
    return bool(ok)


def measure(trees: dict, jobs, repeat: int, threads: int, quick: bool, log=print) -> list[dict]:
    """Run every job ``repeat`` times on every tree; returns one row per (job, tree)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="skelslice-speed-") as tmp:
        for label, tree in trees.items():
            if not byte_compile(tree):
                raise RuntimeError(f"{label}: a source file of the tree does not compile")
            wall, text = _run(_worker_cmd("warm", threads), tree, threads, Path(tmp))
            log(f"{label}: kernels loaded in {wall:.1f} s")
        for job in jobs:
            if job == "png":
                continue                       # measured by the octet runs
            size = SIZES[job][1 if quick else 0]
            runs = {label: [] for label in trees}
            for _ in range(repeat):                    # the trees alternate: a load that comes and goes hits both
                for label, tree in trees.items():
                    work = Path(tmp) / label
                    work.mkdir(exist_ok=True)
                    if job == "octet":
                        r = _octet(tree, size, threads, work)
                    elif job == "ctb":
                        r = _printer_file(tree, size, threads, work)
                    else:
                        _, text = _run(_worker_cmd(job, *size, threads), tree, threads, work)
                        r = json.loads(text.strip().splitlines()[-1])
                    runs[label].append(r)
                    log(f"{job} [{label}]: {r['seconds']:.2f} s")
            for label in trees:
                rows.append(_row(job, label, size, runs[label], "seconds"))
                if job == "octet" and "png" in jobs:
                    rows.append(_row("png", label, (size[1], size[1], size[2]), runs[label], "write_seconds"))
    return rows


def _row(job, label, size, runs, key) -> dict:
    row = {"job": job, "tree": label, "size": list(size), "threads": None,
           "runs_seconds": [r[key] for r in runs], "median_seconds": statistics.median(r[key] for r in runs)}
    if key == "seconds" and "evaluations" in runs[0]:
        row["evaluations"] = runs[0]["evaluations"]
        if any(r["evaluations"] != row["evaluations"] for r in runs):
            row["evaluations_vary"] = True
    if "trace_seconds" in runs[0] and key == "seconds":
        row["median_trace_seconds"] = statistics.median(r["trace_seconds"] for r in runs)
    if "setup_seconds" in runs[0] and key == "seconds":
        row["median_setup_seconds"] = statistics.median(r["setup_seconds"] for r in runs)
    return row


def table(rows, labels) -> str:
    """The comparison table: median seconds per tree, speed-up of the first tree over the others."""
    by = {(r["job"], r["tree"]): r for r in rows}
    jobs = list(dict.fromkeys(r["job"] for r in rows))
    head = ["job", "size"] + [f"{lab} s" for lab in labels] + [f"{lab} evals" for lab in labels]
    if len(labels) > 1:
        head.append(f"speed-up vs {labels[1]}")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for job in jobs:
        first = by[(job, labels[0])]
        cells = [job, " x ".join(map(str, first["size"]))]
        cells += [f"{by[(job, lab)]['median_seconds']:.2f}" for lab in labels]
        cells += [f"{by[(job, lab)]['evaluations']:,}" if "evaluations" in by[(job, lab)] else "-"
                  for lab in labels]
        if len(labels) > 1:
            other = by[(job, labels[1])]["median_seconds"]
            cells.append(f"{other / first['median_seconds']:.2f}x" if first["median_seconds"] > 0 else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def trees_to_run(ap: argparse.ArgumentParser, baseline) -> dict:
    """``{"current": this tree}``, plus ``"baseline"`` when ``--baseline`` names
    another source tree (an argparse error if it holds no ``slicer`` package)."""
    trees = {"current": ROOT}
    if baseline is not None:
        if not (baseline / "slicer" / "__init__.py").is_file():
            ap.error(f"--baseline {baseline}: no slicer package there")
        trees["baseline"] = baseline.resolve()
    return trees


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        return worker(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="Another source tree to run (e.g. a 0.1.0 checkout).")
    ap.add_argument("--repeat", type=int, default=3, help="Runs per job and tree; the table shows the median.")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="Tiny sizes: a smoke test of the benchmark itself.")
    ap.add_argument("--jobs", nargs="+", choices=JOBS, default=list(JOBS))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.threads < 1:
        ap.error("--repeat and --threads must be >= 1")
    trees = trees_to_run(ap, args.baseline)
    sys.path.insert(0, str(ROOT))
    from validation import machine

    rows = measure(trees, args.jobs, args.repeat, args.threads, args.quick, log=lambda s: print(s, file=sys.stderr))
    for r in rows:
        r["threads"] = args.threads
    labels = list(trees)
    print(table(rows, labels))
    if args.json is not None:
        doc = {"benchmark": "speed", "command": machine.command_line("python benchmarks/speed.py", argv),
               "machine": machine.describe(), "quick": args.quick, "repeat": args.repeat,
               "threads": args.threads, "trees": labels, "bytecode": "compiled before timing", "rows": rows}
        machine.write_json(args.json, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
