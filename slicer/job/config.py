"""``--config job.toml``: command options from a TOML file.

Precedence is flags > file > defaults: the file's values become click's
``default_map`` for the command, so anything given on the command line wins.
Keys are the command's option names, with dashes or underscores
(``pixel-size`` or ``pixel_size``), plus ``scene`` and ``output``; relative
paths in ``scene`` and ``output`` are relative to the TOML file's folder.
Unknown keys and values of the wrong type are errors naming the file and the
key. Example::

    scene = "lattice.json"
    output = "lattice.sl1s"
    pixel-size = 0.05
    layer-height = 0.05
    max-memory = "4GB"
    executor = "dask"
    scheduler = "tcp://10.0.0.5:8786"
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import click

from slicer.errors import ConfigError

#: keys whose relative paths are resolved against the TOML file's folder
PATH_KEYS = ("scene", "out")


def _names(command: click.Command) -> dict[str, click.Parameter]:
    """Accepted key -> parameter: the parameter name and its long option names."""
    out: dict[str, click.Parameter] = {}
    for p in command.params:
        if p.name in ("config", "help") or getattr(p, "is_eager", False) and p.name != "scene":
            continue
        keys = {p.name}
        for opt in getattr(p, "opts", []):
            if opt.startswith("--"):
                keys.add(opt[2:])
        for k in keys:
            out[k] = p
            out[k.replace("-", "_")] = p
            out[k.replace("_", "-")] = p
    return out


def load_config(path, command: click.Command, ctx: click.Context | None = None) -> dict:
    """Read ``path`` and return a ``default_map`` for ``command``.

    Raises
    ------
    ConfigError
        The file is missing or not TOML, a key is not an option of the
        command, or a value does not convert to the option's type.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a folder, not a config file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file ({exc.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    names = _names(command)
    out: dict = {}
    for key, value in doc.items():
        p = names.get(key)
        if p is None:
            known = sorted({k for k in names if "_" not in k})
            raise ConfigError(f"{path}: unknown key {key!r} for `{command.name}` (known keys: {', '.join(known)})")
        if p.name in out:
            raise ConfigError(f"{path}: key {key!r} sets {p.name!r} a second time")
        if isinstance(value, dict):
            raise ConfigError(f"{path}: key {key!r} must be a value, not a table")
        if p.name in PATH_KEYS and isinstance(value, str) and not Path(value).is_absolute():
            value = str(path.parent / value)
        if ctx is not None:
            try:
                p.type_cast_value(ctx, value)
            except click.BadParameter as exc:
                raise ConfigError(f"{path}: key {key!r}: {exc.message}") from None
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{path}: key {key!r}: bad value {value!r} ({exc})") from None
        out[p.name] = value
    return out


def _callback(ctx: click.Context, param: click.Parameter, value):
    if value is None:
        return None
    defaults = load_config(value, ctx.command, ctx)
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    return value


def config_option(f):
    """Decorator: add ``--config FILE`` to a click command (processed first)."""
    return click.option("--config", type=click.Path(dir_okay=False), default=None, is_eager=True,
                        expose_value=False, callback=_callback, metavar="FILE.toml",
                        help="Read options from a TOML file (flags given here win).")(f)


__all__ = ["ConfigError", "config_option", "load_config"]
