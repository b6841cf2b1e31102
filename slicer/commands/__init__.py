"""CLI commands, one module each. ``COMMANDS`` lists what :mod:`slicer.cli` registers."""
from __future__ import annotations

import importlib

_MODULES = ["lattice", "info", "slice", "printers", "render", "validate", "bench"]


def _load():
    cmds = []
    for name in _MODULES:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:  # command not written yet
            if exc.name == f"{__name__}.{name}":
                continue
            raise
        cmds.append(mod.command)
    return cmds


COMMANDS = _load()
