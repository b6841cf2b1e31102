"""``skelslice warmup``: compile the kernels ahead of time, for container images and cluster machines."""
from __future__ import annotations

import sys

import click

from slicer._jit import cache_root
from slicer.job.warmup import DEFAULT, FEATURES, feature_names, warm_up


@click.command("warmup")
@click.argument("features", nargs=-1, metavar="[FEATURE]...")
@click.option("--all", "all_", is_flag=True, help="Every feature.")
@click.option("--jobs", "-j", type=click.IntRange(min=1), default=None,
              help="Processes compiling at once (default: the cores).")
@click.option("--list", "list_", is_flag=True, help="List the features and what each compiles.")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing; the exit status tells.")
def command(features, all_, jobs, list_, quiet):
    """Compile the kernels of FEATURE... (default: trace, the quick start's) for this machine, in several
    processes, into the compiled cache that later jobs load them from.

    Features: trace, printer, contours, union, sampling, segment, parts, check, render.
    """
    if list_:
        for name, (_, what) in FEATURES.items():
            click.echo(f"{name:10s} {what}")
        return
    if all_ and features:
        raise click.UsageError("give FEATURE names or --all, not both")
    chosen = feature_names(list(FEATURES) if all_ else (list(features) or list(DEFAULT)))
    if not quiet:
        click.echo(f"compiling {', '.join(chosen)} into {cache_root()} ...", err=True)
    shown = (lambda w: click.echo(f"{w.feature:10s} {w.seconds:6.1f} s  "
                                  f"{'ok' if w.status == 0 else 'FAILED: ' + w.error}")) if not quiet else None
    results = warm_up(chosen, jobs, on_done=shown)
    failed = [w for w in results if w.status != 0]
    if failed:
        if quiet:
            for w in failed:
                click.echo(f"error: warmup {w.feature}: {w.error}", err=True)
        sys.exit(1)
