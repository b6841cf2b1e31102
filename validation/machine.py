"""What every benchmark result records: the command that produced it and the machine.

Benchmark scripts (``validation.bench``, ``validation.error_time``,
``validation.stiff``, ``benchmarks/*.py`` and ``skelslice bench``) put
:func:`describe` under ``"machine"`` and :func:`command_line` under
``"command"`` in the JSON they write, so a result can be compared with
another run and re-run. Neither ever holds a local path: a path inside the
repository is written relative to its root, any other absolute path as its
file name only (:func:`portable`).
"""
from __future__ import annotations

import json
import os
import platform
import re
import shlex
import sys
from pathlib import Path

from slicer.atomic import write_bytes

#: the repository (or installed source tree) root: the folder holding ``validation/``
ROOT = Path(__file__).resolve().parent.parent

# an absolute POSIX path: a slash not preceded by a word character, ":" or "/"
# (so "tcp://host:8786", "a/b" and "1/2" are left alone), then path characters
_ABS_PATH = re.compile(r"(?<![\w:/.~-])/[^\s'\",;:()\[\]{}]+")


def cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo`` on Linux), else what
    :mod:`platform` knows, else ``"unknown"``."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip() or "unknown"
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def os_name() -> str:
    """The operating system: distribution (``/etc/os-release``) and kernel.

    Examples
    --------
    >>> platform.system() in os_name()
    True
    """
    distro = ""
    try:
        with open("/etc/os-release", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.startswith("PRETTY_NAME="):
                    distro = line.split("=", 1)[1].strip().strip('"')
                    break
    except OSError:
        pass
    kernel = f"{platform.system()} {platform.release()} {platform.machine()}".strip()
    return f"{distro}, {kernel}" if distro else kernel


def _version(module: str) -> str | None:
    try:
        return __import__(module).__version__
    except Exception:   # noqa: BLE001 - a missing or broken package is simply not recorded
        return None


def describe() -> dict:
    """The machine a benchmark ran on, as a JSON-ready dict.

    Returns
    -------
    dict
        ``cpu`` (model name), ``cores`` (logical CPUs), ``os``, ``python``,
        ``numpy``, ``numba`` and ``skelslice`` versions.

    Examples
    --------
    >>> sorted(describe())
    ['cores', 'cpu', 'numba', 'numpy', 'os', 'python', 'skelslice']
    """
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "os": os_name(),
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "numba": _version("numba"),
        "skelslice": _version("slicer"),
    }


def summary(machine: dict | None = None) -> str:
    """One line for printed tables, e.g. ``AMD EPYC, 2 cores, Debian ..., Python 3.11.7, numba 0.68.1``."""
    m = machine or describe()
    versions = "".join(f", {name} {m[name]}" for name in ("numpy", "numba") if m.get(name))
    return f"{m['cpu']}, {m['cores']} cores, {m['os']}, Python {m['python']}{versions}"


def portable(text: str, root: Path | None = None) -> str:
    """``text`` with every absolute path made portable: relative to the
    repository root when it lies inside it, else its file name only.

    Examples
    --------
    >>> portable("--json /data/run3/out.json --scheduler tcp://10.0.0.5:8786")
    '--json out.json --scheduler tcp://10.0.0.5:8786'
    >>> portable(str(ROOT / "benchmarks" / "results" / "x.json"))
    'benchmarks/results/x.json'
    """
    base = Path(root or ROOT).resolve()

    def one(m: re.Match) -> str:
        p = Path(m.group(0))
        try:
            return p.resolve().relative_to(base).as_posix() or "."
        except ValueError:
            return p.name or "."

    return _ABS_PATH.sub(one, text)


def command_line(prog: str, argv=None) -> str:
    """The command that produced a result, with portable paths.

    Parameters
    ----------
    prog : str
        How the script is run from the repository root, e.g.
        ``"python -m validation.bench"`` or ``"python benchmarks/render_bench.py"``.
    argv : list of str, optional
        Its arguments (default: ``sys.argv[1:]``). Relative paths are taken
        relative to the current folder and written relative to the
        repository root when they lie inside it.

    Examples
    --------
    >>> command_line("python -m validation.stiff", ["--json", "/data/x/stiff.json", "--fast"])
    'python -m validation.stiff --json stiff.json --fast'
    """
    args = list(sys.argv[1:] if argv is None else argv)
    out = []
    for a in args:
        a = str(a)
        if not a.startswith("-") and not os.path.isabs(a) and os.sep in a and os.path.exists(a):
            a = os.path.abspath(a)
        out.append(shlex.quote(portable(a)))
    return " ".join([prog, *out])


__all__ = ["describe", "summary", "command_line", "portable", "cpu_model", "os_name", "write_json", "publish", "ROOT"]


def write_json(path, doc: dict) -> None:
    """Write a benchmark's JSON document to ``path`` atomically (replacing it)."""
    write_bytes(path, (json.dumps(doc, indent=1) + "\n").encode(), force=True)


def publish(res: dict, table: str, json_path=None) -> None:
    """Print a benchmark's command, machine (``res["command"]``, ``res["machine"]``)
    and ``table``; with ``json_path``, also write ``res`` there (:func:`write_json`)."""
    print(f"command: {res['command']}\nmachine: {summary(res['machine'])}")
    print(table)
    if json_path:
        write_json(json_path, res)
