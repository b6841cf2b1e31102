"""The lazy walk's bounds (slicer._kernels.rays.lazy) hold the field on random rays through one segment.

A primitive is bounded at t from its last evaluation at tc alone (unimodality
along the ray): these tests evaluate at a random tc, then check every bound
the lazy walk would use — at points (``bound_at``) and on pieces
(``piece_bounds_iv`` on rows filled by ``bound_at``) — against dense samples
of the compiled field. The ray families are those of tests/test_ray_unimodal.py.
"""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import rays
from sample_lattices import load_sample
from slicer._kernels.field.segment import SCRATCH
from slicer._kernels.rays.lazy import bound_at, eval_dir
from slicer._kernels.rays.walk import piece_bounds_iv
from slicer._kernels.rays.support import H_TIN, H_TOUT
from slicer.render.rendering import render

#: rounding slack of the compiled field relative to the ray's peak
SLACK = 1e-9


def _setup(ray, u):
    s = ray.skel
    rec = ray.rec
    tin, tout = rec[0, H_TIN], rec[0, H_TOUT]
    tc = tin + u * (tout - tin)
    ct = np.full(1, np.nan)
    cf = np.zeros(1)
    cfp = np.zeros(1)
    kp = (s.degree // 2, 1.0 / s.sigma ** 2, s.normalisation)
    eval_dir(ray.seg, np.zeros(1, np.int64), rec, 0, (*ray.o, *ray.d), tc, kp, np.empty(SCRATCH), (ct, cf, cfp))
    return tin, tout, tc, ct, cf, cfp


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(rays(), st.floats(0.01, 0.99), st.floats(0.0, 1.0), st.floats(0.001, 1.0))
def test_bounds_from_one_evaluation_hold(case, u, a, w):
    _, ray, _ = case
    if not ray.hit:
        return
    tin, tout, tc, ct, cf, cfp = _setup(ray, u)
    t = np.linspace(tin, tout, 1201)
    f = ray.field(t)
    scale = SLACK * max(f.max(), cf[0], 1e-300)
    for ti, fi in zip(t, f):
        lo, hi, fp = bound_at(ray.rec, 0, ti, (ct, cf, cfp))
        assert lo - scale <= fi <= hi + scale, (ti, fi, lo, hi, tc, ray.describe())
    # a piece [ta, tb] with both ends bounded (not evaluated): its bound holds every sample on it
    ta = tin + a * (tout - tin)
    tb = min(ta + w * (tout - tin), tout)
    if not tb > ta:
        return
    F = np.zeros((2, 1))
    FH = np.zeros((2, 1))
    FP = np.zeros((2, 1))
    for row, tt in enumerate((ta, tb)):
        F[row, 0], FH[row, 0], FP[row, 0] = bound_at(ray.rec, 0, tt, (ct, cf, cfp))
    mstat = np.zeros(1, np.int64)
    lo, hi, mono = piece_bounds_iv(ray.rec, np.zeros(1, np.int64), 1, F, FH, FP, 0, 1, ta, tb, False, mstat)
    tp = np.linspace(ta, tb, 301)
    fpiece = ray.field(tp)
    assert lo - scale <= fpiece.min() and fpiece.max() <= hi + scale, (ta, tb, lo, hi, tc, ray.describe())
    if mono != 0:
        d = np.diff(fpiece)
        assert np.all(mono * d >= -scale), (ta, tb, mono, tc, ray.describe())


def test_lazy_render_is_the_eager_render():
    """The renderer's lazy walk skips only pieces free of crossings: same image, crossings, roots."""
    for name in ("octet_2x2x2", "jellyfish"):
        s = load_sample(name)
        a = render(s, size=(64, 64), keep_roots=True, threads=2)
        b = render(s, size=(64, 64), keep_roots=True, threads=2, lazy=True)
        assert np.array_equal(a.rgba, b.rgba) and np.array_equal(a.count, b.count)
        assert np.array_equal(a.roots, b.roots)
        assert b.stats["evaluations"] < a.stats["evaluations"]
