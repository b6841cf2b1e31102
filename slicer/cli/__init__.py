"""The command-line interface: ``skelslice COMMAND ...`` (:mod:`slicer.cli.app`), one module per
command in :mod:`slicer.cli.commands`.

The names of :mod:`slicer.cli.app` are importable from here too (``from slicer.cli import ...``),
loaded on first use.
"""
from __future__ import annotations

import importlib


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("slicer.cli.app"), name)
