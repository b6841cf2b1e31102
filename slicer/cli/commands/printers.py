"""``skelslice printers``: the built-in printer profiles."""
from __future__ import annotations

import dataclasses
import json

import click

from formats.printer_profiles import PRINTERS


@click.command("printers")
@click.option("--json", "as_json", is_flag=True, help="Print the table as JSON.")
def command(as_json):
    """List the printer profiles usable with `slice --printer NAME`."""
    if as_json:
        click.echo(json.dumps({n: {**dataclasses.asdict(p), "pixel_size": list(p.pixel_size)}
                               for n, p in sorted(PRINTERS.items())}, indent=1))
        return
    for name in sorted(PRINTERS):
        p = PRINTERS[name]
        click.echo(p.describe())
        click.echo(f"    exposure {p.exposure:g} s, bottom {p.bottom_exposure:g} s x {p.bottom_layers} layers, "
                   f"layer {p.layer_height:g} mm")
