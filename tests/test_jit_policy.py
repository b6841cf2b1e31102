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
    "slicer._kernels.field.segment.segment_eval",
    "slicer._kernels.field.segment.support_interval",
    "slicer._kernels.field.binning.bin_boxes",
    "slicer._kernels.field.points.field_at_points",
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


# --- kernels compiled without reference counting (slicer._jit.unrefcounted_kernel)

UNREFCOUNTED = sorted(name for name, opts in DISPATCHERS.items() if opts.get("_nrt") is False)
#: allocating calls an unrefcounted kernel must not make (Numba refuses most
#: of them without its runtime; this names the rule in the source)
ALLOCATING = {"empty", "zeros", "ones", "full", "array", "arange", "copy", "empty_like", "zeros_like",
              "concatenate", "append"}


def _dispatcher(name: str):
    mod, _, attr = name.rpartition(".")
    return getattr(importlib.import_module(mod), attr)


def _returned_arrays(src: str) -> list[str]:
    """Return expressions of a kernel's source that may hand back an array (a
    reference an unrefcounted kernel must never return: nothing would own
    it): a name the function indexes or asks the shape of, or a slice."""
    import ast
    import textwrap
    tree = ast.parse(textwrap.dedent(src))
    arrays = {node.value.id for node in ast.walk(tree)
              if isinstance(node, (ast.Subscript, ast.Attribute)) and isinstance(node.value, ast.Name)
              and (isinstance(node, ast.Subscript) or node.attr in ("shape", "size", "ndim"))}
    bad = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Return) or node.value is None:
            continue
        parts = node.value.elts if isinstance(node.value, ast.Tuple) else [node.value]
        for part in parts:
            if isinstance(part, ast.IfExp):
                parts.extend([part.body, part.orelse])
            elif isinstance(part, ast.Name) and part.id in arrays:
                bad.append(ast.unparse(part))
            elif isinstance(part, ast.Subscript) and any(isinstance(n, ast.Slice) for n in ast.walk(part.slice)):
                bad.append(ast.unparse(part))
    return bad


def test_the_ray_walks_and_the_field_are_unrefcounted():
    for name in ("slicer._kernels.trace.summed.trace_ray_interval", "slicer._kernels.render.walk.render_ray",
                 "slicer._kernels.field.segment.segment_eval", "slicer._kernels.field.segment.segment_lanes",
                 "slicer._kernels.field.segment.segment_half_lanes", "slicer._kernels.contours.quadtree._classified"):
        assert name in UNREFCOUNTED, name
    # the evaluation along a ray is inlined into those walks: no call, nothing counted
    for name in ("slicer._kernels.rays.walk.eval_along", "slicer._kernels.rays.walk.eval_lanes_along"):
        assert DISPATCHERS[name].get("inline") == "always", name


@pytest.mark.parametrize("name", UNREFCOUNTED)
def test_unrefcounted_kernels_allocate_and_return_no_array(name):
    import ast
    import inspect
    import textwrap
    src = inspect.getsource(_dispatcher(name).py_func)
    calls = {node.func.attr for node in ast.walk(ast.parse(textwrap.dedent(src)))
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)}
    assert not calls & ALLOCATING, (name, calls & ALLOCATING)
    assert _returned_arrays(src) == [], name


def test_returned_array_check_sees_views_and_arrays():
    """Guard the check above: an indexed name, a slice, either inside a
    tuple or a conditional, are reported; scalars read from arrays are not."""
    assert _returned_arrays("def f(a, n):\n    x = a[0]\n    return x, a[1:]\n") == ["a[1:]"]
    assert _returned_arrays("def f(a, n):\n    return n, (a if n else a)\n") == []
    assert _returned_arrays("def f(a, n):\n    a[0] = 1\n    return n, (a if n else a)\n") == ["a", "a"]
    assert _returned_arrays("def f(rows):\n    F = rows[0]\n    return F.shape[0], F[0, 1]\n") == []
    assert _returned_arrays("def f(rows):\n    F = rows[0]\n    return F.shape[0], rows\n") == ["rows"]
