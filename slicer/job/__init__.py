"""A whole slicing job: settings as data (:mod:`slicer.job.spec`), the job itself (:mod:`slicer.job.run`)
and ``--config`` files (:mod:`slicer.job.config`).

The names of :mod:`slicer.job.run` are importable from here too (``from slicer.job import ...``),
loaded on first use.
"""
from __future__ import annotations

import importlib


def __getattr__(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(importlib.import_module("slicer.job.run"), name)
