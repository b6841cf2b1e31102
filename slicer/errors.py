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


__all__ = ["SkelsliceError", "SceneError", "GridError", "OutputError"]
