"""Earlier module paths keep importing (slicer/_aliases.py): code written against the flat layout still runs."""
from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from slicer import _aliases


@pytest.mark.parametrize("old", sorted(_aliases.MOVED))
def test_every_earlier_path_reads_the_module_that_holds_its_code(old):
    alias = importlib.import_module(old)
    target = importlib.import_module(_aliases.MOVED[old])
    public = [n for n in vars(target) if not n.startswith("__")]
    assert public, old
    for name in public:
        assert getattr(alias, name) is getattr(target, name), (old, name)
    assert sorted(dir(alias)) == sorted(dir(target))


def test_earlier_documented_imports_in_a_fresh_process():
    """The imports the docs showed before the folders, each in a process that has imported nothing."""
    code = """
from slicer.slicing import slice_skeleton
from slicer.lattice import generate_lattice
from slicer.rendering import render, Camera
from slicer.render_output import save_png
from slicer.job import run_slice
from slicer.jobspec import SliceJob
from slicer.parts import Part, load_part
from slicer.cli import main
from slicer.field import evaluate
from slicer.grid import make_grid
import slicer.contours, slicer.commands.info, formats.printers
import slicer
assert slice_skeleton is slicer.slice_skeleton and run_slice is slicer.run_slice
assert main.name == "main" or callable(main)
assert formats.printers.get_printer("prusa-sl1s").name
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_an_unknown_path_is_not_invented():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("slicer.no_such_module")
