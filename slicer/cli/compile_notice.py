"""The first-run compile messages on the command line (:mod:`slicer.compiling` logs them).

While a command runs, a handler on the ``skelslice.compile`` logger prints each message on stderr: at once
when compiling starts, and when it ends. On a terminal the start line keeps a count of the seconds so far.
A command run with ``-q`` prints none of it.
"""
from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from typing import Iterator

from slicer.compiling import END, LOG, START


class _Notice(logging.Handler):
    """Prints the compile messages on ``stream``; ticks the seconds on a terminal."""

    def __init__(self, stream):
        super().__init__(logging.INFO)
        self.stream = stream
        self.tty = bool(getattr(stream, "isatty", lambda: False)())
        self._stop: threading.Event | None = None
        self._ticker: threading.Thread | None = None

    def emit(self, record: logging.LogRecord) -> None:
        kind = getattr(record, "skelslice_compile", None)
        text = record.getMessage()
        if kind == START and self.tty:
            self._stop = threading.Event()
            self._ticker = threading.Thread(target=self._tick, args=(text, self._stop), daemon=True)
            self._ticker.start()
            return
        if kind == END and self._ticker is not None:
            self._stop.set()
            self._ticker.join()
            self._ticker = None
            self.stream.write("\r\033[K")
        self.stream.write(text + "\n")
        self.stream.flush()

    def _tick(self, text: str, stop: threading.Event) -> None:
        t0 = time.monotonic()
        while True:
            self.stream.write(f"\r\033[K{text} ... {time.monotonic() - t0:.0f} s")
            self.stream.flush()
            if stop.wait(1.0):
                return


@contextlib.contextmanager
def compile_notices(enabled: bool = True, stream=None) -> Iterator[None]:
    """Print the first-run compile messages on ``stream`` (default: stderr) while the block runs."""
    if not enabled:
        yield
        return
    handler = _Notice(stream if stream is not None else sys.stderr)
    level = LOG.level
    LOG.addHandler(handler)
    if LOG.getEffectiveLevel() > logging.INFO:
        LOG.setLevel(logging.INFO)
    try:
        yield
    finally:
        LOG.removeHandler(handler)
        LOG.setLevel(level)
        if handler._ticker is not None:       # interrupted while compiling
            handler._stop.set()
            handler._ticker.join()
            handler.stream.write("\n")
