"""Hostile 3MF files and a genuine large 3MF mesh part, this tree against another, in one run.

Usage::

    python benchmarks/hostile_inputs.py [--baseline TREE] [--vertices N] [--timeout S] [--json out.json]

Cases (built in a temporary folder):

``comment-64MiB``, ``attribute-64MiB``
    A 3MF whose model part holds a 64 MiB comment or attribute value
    (deflated: about 65 kB), read by ``skelslice info``; and the same with
    ``--max-input-ratio none``, so the model scan meets the token itself.
``vertices-5M-one-triangle``
    A model part of ``--vertices`` vertices and one triangle (about 330 kB).
``genuine-mesh``
    A closed torus mesh part of ``--vertices`` vertices (twice as many
    triangles), read by :func:`slicer.scene.threemf.read_3mf`: the seconds of the
    read, the process's peak memory and a digest of the mesh it returns
    (vertices and faces; the same digest means the same slices).

Each case runs in a fresh subprocess with ``PYTHONPATH`` set to the tree
under test; the table shows its wall-clock and CPU seconds (the process's
user and system time; for the genuine mesh, the read's own), peak resident
memory (MB), exit status and the last line of its message. On a shared
machine compare the CPU seconds. A case past ``--timeout`` seconds
is stopped and shown as ``timeout``. The JSON (``--json``) records the
command and the machine (:mod:`validation.machine`), never a local path.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from speed import trees_to_run  # noqa: E402  (as the speed benchmark does)

CONTENT_TYPES = ('<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxmlformats.org/package/'
                 '2006/content-types"><Default Extension="rels" ContentType="application/vnd.openxmlformats-'
                 'package.relationships+xml"/><Default Extension="model" ContentType="application/vnd.ms-'
                 'package.3dmanufacturing-3dmodel+xml"/></Types>')
RELS = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.openxmlformats.org/package/'
        '2006/relationships"><Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft'
        '.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>')
HEAD = (b'<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" '
        b'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">')
OBJECT = b'<resources><object id="1" type="model"><mesh><vertices>'
TAIL = b'</mesh></object></resources><build><item objectid="1"/></build></model>'
TETRA = (OBJECT + b'<vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" y="1" z="0"/>'
         b'<vertex x="0" y="0" z="1"/></vertices><triangles><triangle v1="0" v2="2" v3="1"/>'
         b'<triangle v1="0" v2="1" v3="3"/><triangle v1="0" v2="3" v3="2"/><triangle v1="1" v2="2" v3="3"/>'
         b'</triangles>' + TAIL)
MIB = 1 << 20


def package(path: Path, pieces) -> Path:
    """A 3MF package whose model part is the concatenation of ``pieces`` (streamed, deflated)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("[Content_Types].xml", CONTENT_TYPES)
        z.writestr("_rels/.rels", RELS)
        with z.open("3D/3dmodel.model", "w", force_zip64=True) as fh:
            for piece in pieces:
                fh.write(piece)
    return path


def _long(prefix: bytes, mib: int, suffix: bytes):
    yield prefix
    for _ in range(mib):
        yield b"a" * MIB
    yield suffix


def _many_vertices(n: int):
    yield HEAD + OBJECT
    block = b'<vertex x="0" y="0" z="0"/>' * 10_000
    for _ in range(n // 10_000):
        yield block
    yield b'</vertices><triangles><triangle v1="0" v2="1" v3="2"/></triangles>' + TAIL


def torus(n_vertices: int, big: float = 30.0, small: float = 10.0):
    """A closed torus grid of about ``n_vertices`` vertices: (v (n, 3) float64 mm, f (2n, 3) int64)."""
    nv = max(8, int(round((n_vertices / 2.5) ** 0.5)))
    nu = max(8, n_vertices // nv)
    u = np.arange(nu) * (2 * np.pi / nu)
    w = np.arange(nv) * (2 * np.pi / nv)
    uu, ww = np.meshgrid(u, w, indexing="ij")
    ring = big + small * np.cos(ww)
    v = np.stack([ring * np.cos(uu), ring * np.sin(uu), small * np.sin(ww)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a, b = i * nv + j, ((i + 1) % nu) * nv + j
    c, d = ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return v, f


def _mesh_pieces(v: np.ndarray, f: np.ndarray):
    yield HEAD + OBJECT
    for k in range(0, len(v), 100_000):
        yield "".join(f'<vertex x="{x:.4f}" y="{y:.4f}" z="{z:.4f}"/>' for x, y, z in v[k:k + 100_000].tolist()).encode()
    yield b"</vertices><triangles>"
    for k in range(0, len(f), 100_000):
        yield "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in f[k:k + 100_000].tolist()).encode()
    yield b"</triangles>" + TAIL


# ---------------------------------------------------------------- worker side
def worker(path: str) -> int:
    """Time :func:`slicer.scene.threemf.read_3mf` on ``path``; print JSON (seconds, digest)."""
    from slicer.scene.threemf import read_3mf

    t, c = time.perf_counter(), time.process_time()
    got = read_3mf(path)
    sec, cpu = time.perf_counter() - t, time.process_time() - c
    h = hashlib.sha256()
    for m in got.solids:
        h.update(np.ascontiguousarray(m.vertices, np.float64).tobytes())
        h.update(np.ascontiguousarray(m.faces, np.int64).tobytes())
    print(json.dumps({"seconds": sec, "cpu_seconds": cpu, "digest": h.hexdigest()[:16],
                      "faces": sum(m.n_faces for m in got.solids)}))
    return 0


# ---------------------------------------------------------------- driver side
def run(tree: Path, args: list[str], timeout: float) -> dict:
    """One subprocess: seconds, peak MB (GNU time's maximum resident size), exit status, last line of
    stderr (or of stdout)."""
    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_NUM_THREADS": "2"}
    timer = ["/usr/bin/time", "-f", "PEAK_KB %M %U %S"] if Path("/usr/bin/time").exists() else []
    t = time.perf_counter()
    proc = subprocess.Popen([*timer, sys.executable, *args], cwd=tree, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
        status = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)              # the timer and the Python process under it
        out, err = proc.communicate()
        status = "timeout"
    sec = time.perf_counter() - t
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("Command ")]
    peak = cpu = None
    if lines and lines[-1].startswith("PEAK_KB "):
        _, kb, user, system = lines.pop().split()
        peak, cpu = round(int(kb) / 1024), round(float(user) + float(system), 2)
    text = lines or out.strip().splitlines()
    return {"seconds": round(sec, 2), "cpu_seconds": cpu, "peak_mb": peak, "exit": status,
            "message": text[-1] if text else "", "stdout": out}


def measure(trees: dict, vertices: int, timeout: float, folder: Path, log) -> list[dict]:
    cases = {
        "comment-64MiB": (package(folder / "comment.3mf", _long(HEAD + b"<!--", 64, b"-->" + TETRA)), []),
        "attribute-64MiB": (package(folder / "attribute.3mf",
                                    _long(HEAD + b'<metadata name="', 64, b'">x</metadata>' + TETRA)), []),
        "vertices-one-triangle": (package(folder / "vertices.3mf", _many_vertices(vertices)), []),
    }
    rows = []
    for name, (path, extra) in cases.items():
        for flags in ([], ["--max-input-ratio", "none"]):
            for tree_name, tree in trees.items():
                if flags and tree_name == "baseline":
                    continue                              # the baseline has no such flag
                log(f"{name} {' '.join(flags)} [{tree_name}]")
                r = run(tree, ["-m", "slicer", *flags, "info", str(path)], timeout)
                r.pop("stdout")
                r["message"] = r["message"].replace(str(path), path.name)[:200]
                rows.append({"case": name + (" (ratio none)" if flags else ""), "tree": tree_name,
                             "bytes": path.stat().st_size, **r})
    v, f = torus(vertices)
    path = package(folder / "torus.3mf", _mesh_pieces(v, f))
    for tree_name, tree in trees.items():
        log(f"genuine mesh of {len(v):,} vertices [{tree_name}]")
        r = run(tree, [str(Path(__file__).resolve()), "--worker", str(path)], max(timeout, 1800))
        got = json.loads(r.pop("stdout")) if r["exit"] == 0 else {}
        rows.append({"case": f"genuine-mesh {len(v):,} vertices", "tree": tree_name, "bytes": path.stat().st_size,
                     "seconds": round(got["seconds"], 2) if got else r["seconds"],
                     "cpu_seconds": round(got["cpu_seconds"], 2) if got else r["cpu_seconds"], "peak_mb": r["peak_mb"],
                     "exit": r["exit"], "message": f"read_3mf, mesh digest {got.get('digest', '-')}"})
    return rows


def table(rows: list[dict]) -> str:
    head = f"{'case':<40} {'tree':<9} {'bytes':>12} {'seconds':>8} {'cpu s':>8} {'peak MB':>8} {'exit':>7}  message"
    lines = [head, "-" * len(head)]
    for r in rows:
        peak = "-" if r["peak_mb"] is None else f"{r['peak_mb']:.0f}"
        cpu = "-" if r["cpu_seconds"] is None else f"{r['cpu_seconds']:.2f}"
        lines.append(f"{r['case']:<40} {r['tree']:<9} {r['bytes']:>12,} {r['seconds']:>8.2f} {cpu:>8} {peak:>8} "
                     f"{r['exit']!s:>7}  {r['message']}")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        return worker(argv[1])
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="Another source tree to run (e.g. an older checkout).")
    ap.add_argument("--vertices", type=int, default=5_000_000, help="Vertices of the large mesh parts.")
    ap.add_argument("--timeout", type=float, default=300.0, help="Seconds before a hostile case counts as a hang.")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    trees = trees_to_run(ap, args.baseline)
    sys.path.insert(0, str(ROOT))
    from validation import machine

    with tempfile.TemporaryDirectory() as tmp:
        rows = measure(trees, args.vertices, args.timeout, Path(tmp), log=lambda s: print(s, file=sys.stderr))
    doc = {"benchmark": "hostile_inputs", "command": machine.command_line("python benchmarks/hostile_inputs.py", argv),
           "machine": machine.describe(), "vertices": args.vertices, "trees": list(trees), "rows": rows}
    machine.publish(doc, table(rows), args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
