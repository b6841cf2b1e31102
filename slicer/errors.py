"""Exception hierarchy.

All errors raised by skelslice derive from :class:`SkelsliceError`; input
problems are also :class:`ValueError` so generic callers can catch them.
The CLI turns any :class:`SkelsliceError` into a one-line message and exit
status 2.
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


class GridError(SkelsliceError, ValueError):
    """A slicing grid or job request is invalid (sizes, bounds, resolution)."""


class OutputError(SkelsliceError, OSError):
    """An output cannot be written (exists, unwritable, disk full)."""


def positive_number(value, name: str, error: type[SkelsliceError]) -> float:
    """``value`` as a finite float > 0, else ``error`` naming ``name`` and the value.

    Booleans are refused (``True`` is not a size).
    """
    import math

    shown = repr(value.item() if hasattr(value, "item") and not isinstance(value, (list, tuple)) else value)
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        raise error(f"{name} must be a number > 0, got {shown}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a number > 0, got {shown}") from None
    if not math.isfinite(v) or v <= 0:
        raise error(f"{name} must be a finite number > 0, got {shown}")
    return v


__all__ = ["SkelsliceError", "SceneError", "GridError", "OutputError", "positive_number"]
