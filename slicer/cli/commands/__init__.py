"""CLI commands, one module each. ``COMMANDS`` lists what :mod:`slicer.cli.app` registers."""
from __future__ import annotations

from slicer.cli.commands import bench, check, info, lattice, mesh, preview, printers, render, validate, warmup
from slicer.cli.commands import slice as slice_
from slicer.cli.commands import supports as supports_

#: the commands, in the order ``skelslice --help`` lists them
COMMANDS = [lattice.command, info.command, slice_.command, check.command, preview.command, printers.command,
            render.command, validate.command, bench.command, supports_.command, mesh.command, warmup.command]

__all__ = ["COMMANDS"]
