"""The README's examples on a fresh machine and again warm: what a new user waits for, in one run.

Usage::

    python benchmarks/cold_start.py [--baseline TREE] [--repeat N] [--examples quick sl1s ...] [--json out.json]

Each example is the README's command, run as a whole process (``python -m slicer ...``) in a scratch
folder, in README order: first in an empty compiled cache of its own (``NUMBA_CACHE_DIR``, shared by the
examples of one round, as one user's machine), then the whole sequence again on the filled cache. Reported
per example: the seconds cold and warm, and the seconds to the first line the command prints (cold; the
first-run notice of :mod:`slicer.compiling`), medians of ``--repeat`` rounds. With ``--baseline`` another
checkout runs the same rounds, alternating with this tree. The trees' packages are byte-compiled first,
as ``pip install`` does. The JSON (``--json``) holds every run, the command and the machine
(:mod:`validation.machine`), never a local path.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from speed import byte_compile, trees_to_run  # noqa: E402  (as the speed benchmark does)

#: README examples, in README order: name -> arguments of ``python -m slicer`` (``{s}``: sample_lattices)
EXAMPLES = {
    "quick": ("slice", "{s}/jellyfish.json", "-o", "jellyfish_stack", "--pixel-size", "0.05"),
    "sl1s": ("slice", "{s}/jellyfish.json", "-o", "jellyfish.sl1s", "--printer", "prusa-sl1s", "--aa", "2"),
    "check": ("check", "{s}/jellyfish.json", "--printer", "prusa-sl1s"),
    "preview": ("preview", "jellyfish.sl1s", "-o", "jellyfish.html"),
    "render": ("render", "{s}/jellyfish.json", "-o", "jellyfish.png", "--size", "500", "500"),
    "validate": ("validate", "{s}/cubic_2x2x2.json", "--layers-checked", "4"),
    "lattice": ("lattice", "octet", "--cells", "4", "4", "4", "--cell-size", "5", "--radius", "0.4:0.8", "-o",
                "octet.json"),
    "info": ("info", "octet.json", "--pixel-size", "0.05"),
}


def _run(tree: Path, cache: Path, work: Path, args) -> dict:
    """One example as a whole process: seconds, seconds to its first printed line, exit status."""
    env = {k: v for k, v in os.environ.items() if k not in ("SKELSLICE_NUMBA_CACHE", "PYTHONDONTWRITEBYTECODE")}
    env.update(PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(cache))
    argv = [a.format(s=tree / "sample_lattices") for a in args]
    first = []
    t0 = time.perf_counter()
    force = ["--force"] if argv[0] in ("slice", "preview", "render") else []     # the warm round rewrites
    p = subprocess.Popen([sys.executable, "-m", "slicer", *argv, *force], cwd=work, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)

    def watch(stream):
        line = stream.readline()
        if line and not first:
            first.append(time.perf_counter() - t0)
        stream.read()

    readers = [threading.Thread(target=watch, args=(s,)) for s in (p.stdout, p.stderr)]
    for r in readers:
        r.start()
    status = p.wait()
    for r in readers:
        r.join()
    return {"seconds": time.perf_counter() - t0, "first_line_seconds": first[0] if first else None,
            "status": status}


def measure(trees: dict, examples, repeat: int, log=print) -> list[dict]:
    """``repeat`` rounds per tree (trees alternating): the examples cold in a fresh cache, then warm."""
    runs = {(label, ex): [] for label in trees for ex in examples}
    for tree in trees.values():
        byte_compile(tree)
    for r in range(repeat):
        for label, tree in trees.items():
            with tempfile.TemporaryDirectory(prefix="skelslice-cold-") as tmp:
                cache, work = Path(tmp) / "cache", Path(tmp) / "work"
                work.mkdir()
                for phase in ("cold", "warm"):
                    for ex in examples:
                        res = _run(tree, cache, work, EXAMPLES[ex])
                        log(f"round {r + 1} {label} {phase} {ex}: {res['seconds']:.1f} s (exit {res['status']})")
                        runs[(label, ex)].append({"phase": phase, **res})
    rows = []
    for (label, ex), rs in runs.items():
        med = lambda phase, key: statistics.median(x[key] for x in rs if x["phase"] == phase and x[key] is not None)
        rows.append({"example": ex, "tree": label, "command": "skelslice " + " ".join(EXAMPLES[ex]).replace(
            "{s}", "sample_lattices"), "runs": rs, "median_cold_seconds": med("cold", "seconds"),
            "median_warm_seconds": med("warm", "seconds"),
            "median_cold_first_line_seconds": med("cold", "first_line_seconds")})
    return rows


def table(rows, labels) -> str:
    head = "| example | " + " | ".join(f"{t} cold | {t} first line | {t} warm" for t in labels) + " |"
    lines = [head, "|" + "---|" * (1 + 3 * len(labels))]
    for ex in dict.fromkeys(r["example"] for r in rows):
        cells = []
        for t in labels:
            r = next(x for x in rows if x["example"] == ex and x["tree"] == t)
            failed = " (failed)" if any(x["status"] not in (0, 1) for x in r["runs"]) else ""
            cells += [f"{r['median_cold_seconds']:.1f} s{failed}", f"{r['median_cold_first_line_seconds']:.1f} s",
                      f"{r['median_warm_seconds']:.1f} s"]
        lines.append(f"| {ex} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="Another source tree to run in the same rounds.")
    ap.add_argument("--repeat", type=int, default=1, help="Rounds per tree; the table shows medians.")
    ap.add_argument("--examples", nargs="+", choices=list(EXAMPLES), default=list(EXAMPLES))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")
    if "preview" in args.examples and "sl1s" not in args.examples:
        ap.error("--examples preview reads the file sl1s writes: give sl1s too")
    if "info" in args.examples and "lattice" not in args.examples:
        ap.error("--examples info reads the file lattice writes: give lattice too")
    trees = trees_to_run(ap, args.baseline)
    sys.path.insert(0, str(ROOT))
    from validation import machine

    rows = measure(trees, args.examples, args.repeat, log=lambda s: print(s, file=sys.stderr))
    print(table(rows, list(trees)))
    if args.json is not None:
        doc = {"benchmark": "cold_start", "command": machine.command_line("python benchmarks/cold_start.py", argv),
               "machine": machine.describe(), "repeat": args.repeat, "trees": list(trees), "rows": rows}
        machine.write_json(args.json, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
