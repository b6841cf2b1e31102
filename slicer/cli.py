"""Command-line interface: ``skelslice COMMAND ...``.

The group only parses and dispatches; each command lives in
:mod:`slicer.commands`.
Any :class:`~slicer.errors.SkelsliceError` becomes a one-line message on
stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import sys

import click

from .commands import COMMANDS
from .errors import SkelsliceError


class _Group(click.Group):
    """Click group that turns skelslice errors into ``error: ...`` + exit 2."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except SkelsliceError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="skelslice")
def main() -> None:
    """skelslice: slice skeleton-based integral surfaces into printer layers."""


for _cmd in COMMANDS:
    main.add_command(_cmd)

if __name__ == "__main__":  # pragma: no cover
    main()
