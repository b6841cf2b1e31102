"""Command-line interface: ``skelslice COMMAND ...``.

The group only parses and dispatches; each command lives in
:mod:`slicer.cli.commands`.
Any :class:`~slicer.errors.SkelsliceError` becomes a one-line message on
stderr and exit status 2, never a traceback.

SIGTERM (what ``kill``, ``timeout`` and job schedulers send) is handled like
Ctrl-C: while a command runs, it raises :class:`SystemExit` (status 143,
128 + SIGTERM) in the main thread, so every writer's abort path removes its
hidden temporary output, as it does for :class:`KeyboardInterrupt`.
"""
from __future__ import annotations

import contextlib
import math
import signal
import sys
import threading

import click

from slicer import input_limits
from slicer.cli.commands import COMMANDS
from slicer.cli.compile_notice import compile_notices
from slicer.errors import OptionError, SkelsliceError
from slicer.scale.tileplan import parse_size


#: exit status after SIGTERM (the shell's 128 + signal number)
TERMINATED = 128 + signal.SIGTERM


def _on_sigterm(signum, frame):
    click.echo("error: terminated (SIGTERM)", err=True)
    raise SystemExit(TERMINATED)


@contextlib.contextmanager
def _sigterm_as_exit():
    """While the block runs, SIGTERM raises SystemExit in the main thread
    (restored afterwards; left alone off the main thread, or where SIGTERM is
    ignored or already handled, as Python treats SIGINT)."""
    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


class _Group(click.Group):
    """Click group that turns skelslice errors into ``error: ...`` + exit 2,
    and SIGTERM into a clean exit (status 143) like Ctrl-C."""

    def invoke(self, ctx):
        with _sigterm_as_exit():
            try:
                return super().invoke(ctx)
            except SkelsliceError as exc:
                click.echo(f"error: {exc}", err=True)
                sys.exit(2)
            except Exception as exc:
                interrupt = _interruption(exc)
                if interrupt is None:
                    raise
                raise interrupt from None


def _interruption(exc: BaseException) -> BaseException | None:
    """The SIGTERM exit or Ctrl-C behind ``exc``, if any.

    A signal that arrives while compiled code calls back into Python (Numba's
    dispatcher) surfaces as a :class:`SystemError` whose cause is the
    handler's :class:`SystemExit` (or the :class:`KeyboardInterrupt`); the
    abort paths have run by then, so the command ends as the signal asked.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, (SystemExit, KeyboardInterrupt)):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def _input_size(ctx, param, value):
    """``--max-input-bytes``: a size (``1GiB``, ``800MB``, ``none``) in bytes, or None."""
    try:
        return parse_size(value)
    except OptionError as exc:
        raise click.BadParameter(str(exc).replace("--max-memory", param.opts[0])) from None


def _input_ratio(ctx, param, value):
    """``--max-input-ratio``: a number >= 1, or None (``none``)."""
    text = str(value).strip().lower()
    if text in ("none", "unlimited", "0"):
        return None
    try:
        r = float(text)
    except ValueError:
        r = math.nan
    if not (math.isfinite(r) and r >= 1):
        raise click.BadParameter(f"{param.opts[0]} must be a number >= 1 or none, got {value!r}")
    return r


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="skelslice")
@click.option("--max-input-bytes", default="1GiB", show_default=True, metavar="SIZE", callback=_input_size,
              help="Most uncompressed bytes the readers take from one archive member (3MF part, zip stack "
                   "or printer-file member), and the largest array a count declared in an input file may ask "
                   "for (e.g. 4GiB; none: no limit).")
@click.option("--max-input-ratio", default="200", show_default=True, metavar="N", callback=_input_ratio,
              help="Most uncompressed / compressed size of an archive member past its first MiB "
                   "(none: no limit).")
def main(max_input_bytes, max_input_ratio) -> None:
    """skelslice: slice skeleton-based integral surfaces into printer layers."""
    input_limits.configure(max_input_bytes, max_input_ratio)


def _with_compile_notices(cmd: click.Command) -> click.Command:
    """``cmd`` printing the first-run compile messages on stderr, unless run with ``-q``."""
    invoke = cmd.invoke

    def run(ctx: click.Context):
        with compile_notices(enabled=not ctx.params.get("quiet", False)):
            return invoke(ctx)

    cmd.invoke = run
    return cmd


for _cmd in COMMANDS:
    main.add_command(_with_compile_notices(_cmd))

if __name__ == "__main__":  # pragma: no cover
    main()
