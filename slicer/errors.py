"""Exception hierarchy.

All errors raised by skelslice derive from :class:`SkelsliceError`; the CLI
turns any of them into a one-line message and exit status 2, never a
traceback. Input problems are also :class:`ValueError` and output problems
:class:`OSError`, so generic callers can catch them.

::

    SkelsliceError
    ├── SceneError (ValueError)            a scene file or array is malformed
    ├── UsageError (ValueError)            a request cannot be carried out as asked
    │   ├── OptionError                    an option value is invalid or options conflict
    │   │   └── ConfigError                a --config file is unreadable or has bad keys
    │   ├── GridError                      the slicing grid or job does not work out
    │   └── FormatError                    the output format cannot hold the job
    ├── MissingDependencyError (ImportError)  an optional package is not installed
    ├── ReadError (ValueError)             a file in an output format cannot be read back
    └── OutputError (OSError)              an output cannot be written (or a writer is misused)
"""
from __future__ import annotations


class SkelsliceError(Exception):
    """Base class of every error raised by skelslice."""


class SceneError(SkelsliceError, ValueError):
    """A scene (file or arrays) is malformed.

    Parameters
    ----------
    message : str
        What is wrong, naming the entry and the offending value.
    source : str, optional
        File the scene came from; prefixed to the message.
    """

    def __init__(self, message: str, source: str | None = None):
        self.source = source
        self.detail = message
        super().__init__(f"{source}: {message}" if source else message)


class UsageError(SkelsliceError, ValueError):
    """A request cannot be carried out as asked (parent of option, grid and format errors)."""


class OptionError(UsageError):
    """An option or argument value is invalid, or options conflict (the message names them)."""


class ConfigError(OptionError):
    """A ``--config`` file cannot be read or has unknown keys or bad values."""


class GridError(UsageError):
    """A slicing grid or job request is invalid (sizes, bounds, resolution, plate fit)."""


class FormatError(UsageError):
    """The chosen output format cannot hold the job (resolution, exposure or layer ranges,
    grey levels); raised before any work."""


class MissingDependencyError(SkelsliceError, ImportError):
    """An optional dependency is not installed.

    Parameters
    ----------
    package : str
        The import name that is missing.
    extra : str
        The skelslice extra that installs it (``pip install 'skelslice[extra]'``).
    needed_for : str
        What needs it, e.g. ``"3MF input"``.
    """

    def __init__(self, package: str, extra: str, needed_for: str):
        self.package, self.extra, self.needed_for = package, extra, needed_for
        super().__init__(f"{needed_for} needs the Python package {package!r}, which is not installed; "
                         f"install it with: pip install 'skelslice[{extra}]'")


class ReadError(SkelsliceError, ValueError):
    """A file in one of the output formats cannot be read back (the readers in :mod:`formats`)."""


class OutputError(SkelsliceError, OSError):
    """An output cannot be written (exists, unwritable, disk full), or a writer is used out of
    its protocol (layers out of order, a layer of the wrong size)."""


def require(package: str, extra: str, needed_for: str):
    """Import an optional dependency, or raise :class:`MissingDependencyError`.

    Examples
    --------
    >>> require("json", "none", "a test").__name__
    'json'
    """
    import importlib

    try:
        return importlib.import_module(package)
    except ImportError:
        raise MissingDependencyError(package, extra, needed_for) from None


__all__ = ["SkelsliceError", "SceneError", "UsageError", "OptionError", "ConfigError", "GridError",
           "FormatError", "MissingDependencyError", "ReadError", "OutputError", "require"]
