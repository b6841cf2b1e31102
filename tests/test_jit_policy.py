"""JIT policy: every compiled kernel keeps IEEE semantics (no fastmath) and the
numpy error model (x/0 -> inf, never an exception), see slicer/_jit.py."""
from __future__ import annotations

import importlib
import pkgutil

import pytest

import slicer._kernels as kernels_pkg

#: kernels known to exist when this test was written (field, binning, points);
#: discovery must find at least this many, so a broken walk cannot pass silently
MIN_DISPATCHERS = 7
KNOWN = {
    "slicer._kernels.field.segment_eval",
    "slicer._kernels.field.support_interval",
    "slicer._kernels.binning.bin_boxes",
    "slicer._kernels.points.field_at_points",
}


def _modules():
    mods = [kernels_pkg]
    for info in pkgutil.walk_packages(kernels_pkg.__path__, prefix=kernels_pkg.__name__ + "."):
        mods.append(importlib.import_module(info.name))
    return mods


def _dispatchers():
    found = {}
    for mod in _modules():
        for attr, obj in vars(mod).items():
            opts = getattr(obj, "targetoptions", None)
            if not isinstance(opts, dict) or not callable(obj):
                continue
            # count each kernel once, under the module that defines it
            py = getattr(obj, "py_func", None)
            home = getattr(py, "__module__", mod.__name__)
            name = f"{home}.{getattr(py, '__name__', attr)}"
            found[name] = opts
    return found


DISPATCHERS = _dispatchers()


def test_discovery_finds_the_kernels():
    assert len(DISPATCHERS) >= MIN_DISPATCHERS, sorted(DISPATCHERS)
    assert KNOWN <= set(DISPATCHERS), KNOWN - set(DISPATCHERS)


@pytest.mark.parametrize("name", sorted(DISPATCHERS))
def test_no_fastmath(name):
    assert not DISPATCHERS[name].get("fastmath", False), DISPATCHERS[name]


@pytest.mark.parametrize("name", sorted(DISPATCHERS))
def test_numpy_error_model(name):
    assert DISPATCHERS[name].get("error_model") == "numpy", DISPATCHERS[name]
