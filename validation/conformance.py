"""Run the 3MF reader over conformance files and tally how they behave.

The 3MF Consortium publishes files a consumer must accept and files it must
refuse (``P_...`` / ``MUSTPASS...`` and ``N_...`` / ``MUSTFAIL...``; lib3mf's
test files mark negatives with ``Negative``, ``_Fail`` or ``MustFail``). Each
file is read as :func:`slicer.parts.part.load_part` reads a scene; the outcome is
"accepted", "refused" (a :class:`~slicer.errors.SkelsliceError` naming the
problem) or "crashed" (anything else: a bug). A must-pass file that requires
an extension skelslice does not print may be refused, by that extension's
name: the core specification tells consumers to do so.

Run: ``python -m validation.conformance FOLDER... [--json FILE]`` (prints one
line per file and the tally).
"""
from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from slicer.atomic import write_bytes
from slicer.errors import SkelsliceError
from slicer.parts.part import load_part

_NEGATIVE = re.compile(r"(^N_|MUSTFAIL|MustFail|Negative|_Fail\b|_Fail\.|MustWarnOrFail)", re.I)
_POSITIVE = re.compile(r"(^P_|MUSTPASS)", re.I)
_BY_EXTENSION = "which skelslice does not support"


def expectation(name: str) -> str:
    """``must-pass``, ``must-fail`` or ``unknown``, from a conformance file's name."""
    if _NEGATIVE.search(name):
        return "must-fail"
    if _POSITIVE.search(name):
        return "must-pass"
    return "unknown"


def check(path: Path) -> dict:
    """Read one file; returns ``file``, ``expect``, ``outcome``, ``message`` and ``ok``."""
    expect = expectation(path.name)
    try:
        part = load_part(path)
        outcome, message = "accepted", part.describe()
    except SkelsliceError as exc:
        outcome, message = "refused", str(exc).replace(str(path) + ": ", "")
    except Exception as exc:          # a crash is a finding, not a refusal
        outcome, message = "crashed", f"{type(exc).__name__}: {exc}"
    ok = {"must-pass": outcome == "accepted" or (outcome == "refused" and _BY_EXTENSION in message),
          "must-fail": outcome == "refused", "unknown": outcome != "crashed"}[expect]
    return {"file": path.name, "expect": expect, "outcome": outcome, "message": message, "ok": ok}


def run(folders) -> list[dict]:
    files = sorted(p for f in folders for p in Path(f).rglob("*.3mf"))
    return [check(p) for p in files]


def tally(rows: list[dict]) -> dict:
    out = {}
    for e in ("must-pass", "must-fail", "unknown"):
        rs = [r for r in rows if r["expect"] == e]
        out[e] = {"files": len(rs), "as_expected": sum(r["ok"] for r in rs),
                  "accepted": sum(r["outcome"] == "accepted" for r in rs),
                  "refused": sum(r["outcome"] == "refused" for r in rs),
                  "crashed": sum(r["outcome"] == "crashed" for r in rs)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    rows = run(a.folders)
    for r in rows:
        mark = "ok " if r["ok"] else "BAD"
        print(f"{mark} {r['expect']:<9} {r['outcome']:<8} {r['file']}: {r['message'][:150]}")
    t = tally(rows)
    for e, c in t.items():
        print(f"{e:<9}: {c['files']} files, {c['as_expected']} as expected "
              f"(accepted {c['accepted']}, refused {c['refused']}, crashed {c['crashed']})")
    if a.json:
        write_bytes(a.json, (json.dumps({"files": rows, "tally": t}, indent=1) + "\n").encode(), force=True)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
