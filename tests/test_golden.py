"""Binary layers pinned to release 0.1.0's: every sample (plain and strict) and every stiff case.

The hashes in tests/data/golden_layers.json were computed by
``PYTHONPATH=<0.1.0 checkout> python benchmarks/golden_layers.py --out tests/data/golden_layers.json``:
a faster tracer must classify every voxel centre exactly as 0.1.0 did.
"""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from sample_lattices import SAMPLES
from slicer.tracer.slicing import SliceResult
from validation.stiff import CASE_NAMES

ROOT = Path(__file__).resolve().parent.parent
REF = json.loads((ROOT / "tests" / "data" / "golden_layers.json").read_text())


def _golden():
    spec = importlib.util.spec_from_file_location("golden_layers", ROOT / "benchmarks" / "golden_layers.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_reference_covers_samples_and_stiff_suite():
    names = set(REF["cases"])
    assert {f"sample:{s}" for s in SAMPLES} | {f"sample:{s}:strict" for s in SAMPLES} <= names
    assert {f"stiff:{c}" for c in CASE_NAMES} <= names


@pytest.fixture(scope="module")
def now():
    return _golden().compute()


@pytest.mark.parametrize("name", sorted(REF["cases"]))
def test_layers_identical_to_0_1_0(now, name):
    assert now[name] == REF["cases"][name]


@pytest.fixture(scope="module")
def now_lazy():
    return _golden().compute(lazy=True)


@pytest.mark.parametrize("name", sorted(REF["cases"]))
def test_lazy_walk_layers_identical_to_0_1_0(now_lazy, name):
    assert now_lazy[name] == REF["cases"][name]


def test_hash_sees_one_voxel():
    g = _golden()
    a = SliceResult(None, np.array([3]), np.array([1]), np.array([5]))
    b = SliceResult(None, np.array([3]), np.array([1]), np.array([6]))
    assert g.runs_hash(a) != g.runs_hash(b)
