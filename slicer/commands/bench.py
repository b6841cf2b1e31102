"""``skelslice bench``: benchmarks, one flag each (``--error``, ``--table1``)."""
from __future__ import annotations

from pathlib import Path

import click


def _bench_error(model, quick, repeat, threads):
    from validation.error_time import format_table, label, plot, sweep

    res = sweep(model, quick=quick, repeat=repeat, threads=threads,
                progress=lambda r: click.echo(f"  {label(r)}: {r['seconds']:.3f} s, "
                                              f"{r['error_layer'] * 1e3:.3f} um", err=True))
    click.echo(format_table(res))
    return res, plot


def _bench_table1(model, quick, repeat, threads):
    from validation.bench import format_table, table1

    models = (model,) if model else ("jellyfish", "microstructure")
    res = table1(models=models, layers=(128,) if quick else (512, 1024), threads=threads, repeat=repeat)
    click.echo(format_table(res))
    return res, None


#: flag -> runner(model, quick, repeat, threads) -> (results, plotter or None);
#: a new benchmark is one more runner here and one more flag below
BENCHMARKS = {"error": _bench_error, "table1": _bench_table1}


@click.command("bench")
@click.option("--error", "which", flag_value="error",
              help="Error against run time for every method and a sweep of its knobs (validation/error_time.py).")
@click.option("--table1", "which", flag_value="table1",
              help="The paper's Table 1 protocol (validation/bench.py).")
@click.option("--model", default=None, help="Sample model (default: jellyfish for --error, both for --table1).")
@click.option("--quick", is_flag=True, help="A smaller sweep (minutes less; for a first look).")
@click.option("--repeat", type=click.IntRange(min=1), default=1, show_default=True, help="Best of N runs.")
@click.option("--threads", type=click.IntRange(min=1), default=None, help="Threads (default: all cores).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None, help="Write the results here.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="Write the plot here (--error; needs matplotlib: pip install 'skelslice[plot]').")
def command(which, model, quick, repeat, threads, json_path, plot_path):
    """Run a benchmark and print its table; timings depend on the machine and its load."""
    import json

    from slicer.errors import GridError, OutputError

    if which is None:
        raise GridError(f"choose a benchmark: {', '.join('--' + k for k in BENCHMARKS)}")
    run = BENCHMARKS[which]
    if plot_path is not None:
        if which != "error":
            raise GridError("--plot is only available with --error")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise OutputError("--plot needs matplotlib: pip install 'skelslice[plot]'") from None
    for p in (json_path, plot_path):
        if p is not None and not Path(p).resolve().parent.is_dir():
            raise OutputError(f"{p}: the folder {Path(p).parent} does not exist")
    res, plotter = run(model or ("jellyfish" if which == "error" else None), quick, repeat, threads)
    if json_path:
        from validation.machine import command_line

        args = [f"--{which}"] + (["--model", model] if model else []) + (["--quick"] if quick else []) \
            + (["--repeat", str(repeat)] if repeat != 1 else []) + (["--threads", str(threads)] if threads else []) \
            + ["--json", json_path] + (["--plot", plot_path] if plot_path else [])
        res = {"command": command_line("skelslice bench", args), **res}
        Path(json_path).write_text(json.dumps(res, indent=1) + "\n")
        click.echo(f"results -> {json_path}")
    if plot_path and plotter:
        plotter(res, plot_path)
        click.echo(f"plot -> {plot_path}")
