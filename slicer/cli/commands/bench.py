"""``skelslice bench``: benchmarks as subcommands (``error``, ``table1``).

``skelslice bench --error ...`` and ``skelslice bench --table1 ...`` (the
first form of this command) keep working: the flags select the subcommand.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import click

from sample_lattices import SAMPLES
from validation.bench import format_table as table1_table
from validation.bench import table1
from validation.bulge import bulge
from validation.bulge import format_table as bulge_table
from validation.parts_bench import format_table as parts_table
from validation.parts_bench import run as parts_bench
from validation.error_time import format_table as error_table
from validation.error_time import label, plot, sweep
from validation.machine import command_line

from slicer.atomic import write_bytes
from slicer.errors import OptionError, OutputError, require


def _bench_error(model, quick, repeat, threads):
    res = sweep(model or "jellyfish", quick=quick, repeat=repeat, threads=threads,
                progress=lambda r: click.echo(f"  {label(r)}: {r['seconds']:.3f} s, "
                                              f"{r['error_layer'] * 1e3:.3f} um", err=True))
    click.echo(error_table(res))
    return res, plot


def _bench_table1(model, quick, repeat, threads):
    models = (model,) if model else ("jellyfish", "microstructure")
    res = table1(models=models, layers=(128,) if quick else (512, 1024), threads=threads, repeat=repeat)
    click.echo(table1_table(res))
    return res, None


def _bench_bulge(model, quick, repeat, threads):
    rows = bulge(rays=1000 if quick else 4000)
    click.echo(bulge_table(rows, 12, 0.5))
    return rows, None


def _bench_parts(model, quick, repeat, threads):
    res = parts_bench(scale=0.5 if quick else 1.0, threads=threads, repeat=repeat)
    click.echo(parts_table(res))
    return res, None


#: suffixes the error plot can be written as
PLOT_SUFFIXES = (".png", ".svg", ".pdf")

#: benchmark name -> runner(model, quick, repeat, threads) -> (results, plotter or None)
BENCHMARKS = {"error": _bench_error, "table1": _bench_table1, "bulge": _bench_bulge, "parts": _bench_parts}


def _common(f):
    for d in reversed([
        click.option("--model", default=None, help="Sample model (default: jellyfish for error, both for table1)."),
        click.option("--quick", is_flag=True, help="A smaller sweep (minutes less; for a first look)."),
        click.option("--repeat", type=click.IntRange(min=1), default=1, show_default=True, help="Best of N runs."),
        click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores)."),
        click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None,
                     help="Write the results here."),
    ]):
        f = d(f)
    return f


_plot_option = click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
                            help="Write the plot here (error only; needs matplotlib: pip install 'skelslice[plot]').")


def run_benchmark(which, model, quick, repeat, threads, json_path, plot_path=None) -> None:
    """Run benchmark ``which``; print its table, write the JSON and the plot (checked before any work)."""
    if which not in BENCHMARKS:
        raise OptionError(f"unknown benchmark {which!r}; choose one of {', '.join(BENCHMARKS)}")
    if plot_path is not None:
        if which != "error":
            raise OptionError("--plot is only available with the error benchmark")
        if Path(plot_path).suffix.lower() not in PLOT_SUFFIXES:
            raise OptionError(f"--plot {plot_path}: the plot is written as {', '.join(PLOT_SUFFIXES)} "
                              f"(from the suffix), got {Path(plot_path).suffix or 'no suffix'}")
        if json_path is not None and Path(json_path).resolve() == Path(plot_path).resolve():
            raise OptionError(f"--json and --plot are the same file {json_path}")
        require("matplotlib", "plot", "--plot")
    if model is not None and model not in SAMPLES:
        raise OptionError(f"unknown --model {model!r}; choose one of {', '.join(sorted(SAMPLES))}")
    if model is not None and which in ("bulge", "parts"):
        raise OptionError(f"--model does not apply to the {which} benchmark (it builds its own scenes)")
    for p in (json_path, plot_path):
        if p is not None and (str(p).endswith(("/", os.sep)) or Path(p).is_dir()):
            raise OutputError(f"{p}: a folder; give a file name")
        if p is not None and not Path(p).resolve().parent.is_dir():
            raise OutputError(f"{p}: the folder {Path(p).parent} does not exist")
    res, plotter = BENCHMARKS[which](model, quick, repeat, threads)
    if json_path:
        args = [which] + (["--model", model] if model else []) + (["--quick"] if quick else []) \
            + (["--repeat", str(repeat)] if repeat != 1 else []) + (["--threads", str(threads)] if threads else []) \
            + ["--json", json_path] + (["--plot", plot_path] if plot_path else [])
        res = {"command": command_line("skelslice bench", args), **res}
        write_bytes(json_path, (json.dumps(res, indent=1) + "\n").encode(), force=True)
        click.echo(f"results -> {json_path}")
    if plot_path and plotter:
        plotter(res, plot_path)
        click.echo(f"plot -> {plot_path}")


@click.group("bench", invoke_without_command=True)
@click.option("--error", "error_flag", is_flag=True, help="Same as `bench error`.")
@click.option("--table1", "table1_flag", is_flag=True, help="Same as `bench table1`.")
@_common
@_plot_option
@click.pass_context
def command(ctx, error_flag, table1_flag, **options):
    """Run a benchmark and print its table; timings depend on the machine and its load.

    \b
    skelslice bench error [--quick] [--json FILE] [--plot FILE.png]
    skelslice bench table1 [--model NAME] [--repeat N]
    skelslice bench bulge [--quick]
    skelslice bench parts [--quick] [--repeat N]
    """
    if error_flag and table1_flag:
        raise OptionError("give one of --error and --table1, not both")
    which = "error" if error_flag else "table1" if table1_flag else None
    if ctx.invoked_subcommand is not None:
        if which is not None:
            raise OptionError(f"give either --{which} or the `{ctx.invoked_subcommand}` subcommand, not both")
        return
    if which is None:
        raise OptionError(f"choose a benchmark: {', '.join(BENCHMARKS)} "
                          f"(e.g. `skelslice bench error --quick`)")
    run_benchmark(which, **options)


@command.command("error")
@_common
@_plot_option
def error_command(**options):
    """Error against run time for every method and a sweep of its knobs (validation/error_time.py)."""
    run_benchmark("error", **options)


@command.command("table1")
@_common
def table1_command(**options):
    """The paper's Table 1 protocol (validation/bench.py)."""
    run_benchmark("table1", **options)


@command.command("bulge")
@_common
def bulge_command(**options):
    """Node bulge of each blend at a 12-valent node (validation/bulge.py)."""
    run_benchmark("bulge", **options)


@command.command("parts")
@_common
def parts_command(**options):
    """What mesh slicing and the booleans cost in a part's job (validation/parts_bench.py)."""
    run_benchmark("parts", **options)
