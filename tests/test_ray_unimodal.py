"""One tapered segment along any ray, through the tracer's own kernels.

The non-strict tracer (``--strict`` off) relies on one segment's field being
unimodal along every ray (docs/math.md §3.3): per primitive, a piece whose ends
both slope up is taken as increasing, and an ambiguous piece is bounded
below by its smaller end value. These tests call the kernels that do this —
:func:`slicer._kernels.rays.support.ray_support` (support entry and exit, the
cut ``t*``, the whole-ray bound ``H_FMAX``), :func:`slicer._kernels.rays.walk.eval_along`
and :func:`slicer._kernels.rays.walk.piece_bounds` — on random rays in any
direction, over taper ratios r1/r0 from 1 to 1e4, nested end balls
(sigma |r1 - r0| > L), the critical tapers the code special-cases (E = 0:
L = sigma |r1 - r0|; A = 0: the ray parallel to a generator of the support
cone) and rays along the axis, and compare with dense sampling of the
field:

* the field is zero outside ``[t_in, t_out]`` (a miss is a real miss);
* it is unimodal on ``[t_in, t_out]`` (non-decreasing, then non-increasing);
* ``H_FMAX`` is never below it;
* on every piece (cut at ``t*`` and at random points), both the unimodal and
  the strict bounds of ``piece_bounds`` hold every sampled value, a piece it
  calls monotone is monotone, and the slope stays within the directional
  Lipschitz bound.

Dense samples use the compiled field (``Skeleton.field``). Where they show a
departure from monotonicity larger than 1e-12 of the peak, the extended
precision quadrature of :mod:`validation.reference_field` decides: the
compiled field is accurate to 1e-10 relative (5e-9 for degree 16), so such a
departure can be its rounding; the test fails only if the reference itself
is not monotone there.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slicer import Skeleton
from slicer._kernels.field.segment import SCRATCH
from slicer._kernels.runtime.launch import serial
from slicer._kernels.rays.walk import eval_along, piece_bounds
from slicer._kernels.rays.support import H_FMAX, H_TIN, H_TOUT, H_TSTAR, NHIT, kprime_max, lipschitz, ray_support
from slicer.model.field import segment_table
from validation import reference_field as ref

#: samples of the field on [t_in, t_out] (and on each piece)
DENSE = 3001
PIECE = 301
#: monotonicity departures below this fraction of the peak are not examined
NOISE = 1e-12
#: the compiled field's accuracy relative to the reference (tests/test_field.py,
#: validation/stiff.py: 1e-10; degree 16: 5e-9)
REL, REL16 = 1e-10, 5e-9


class Ray:
    """One segment and one ray ``o + t d``, with the kernels' view of them."""

    def __init__(self, skel: Skeleton, o, d):
        self.skel = skel
        self.o = np.asarray(o, float)
        self.d = np.asarray(d, float)
        self.seg = segment_table(skel)
        n, sigma, norm = skel.degree, skel.sigma, skel.normalisation
        self.rec = np.zeros((1, NHIT))
        self.hit = ray_support(self.seg, 0, *self.o, *self.d, n, sigma, norm, kprime_max(n, sigma, norm),
                               self.rec, 0)

    def points(self, t):
        return self.o + np.asarray(t, float)[:, None] * self.d

    def field(self, t):
        return self.skel.field(self.points(t))

    def slope(self, t):
        return self.skel.gradient(self.points(t)) @ self.d

    def exact(self, t):
        """The extended-precision reference at ``o + t d``."""
        s = self.skel
        a, b = s.nodes[s.segments[0, 0]], s.nodes[s.segments[0, 1]]
        f = ref.segment_field(a, b, s.radii[0, 0], s.radii[0, 1], self.points(t), degree=s.degree, sigma=s.sigma)
        return np.asarray(f[0] if isinstance(f, tuple) else f, dtype=float)

    def piece(self, ta, tb, strict):
        """piece_bounds for [ta, tb], the ends evaluated with eval_along."""
        s = self.skel
        hprim = np.zeros(1, np.int64)
        sarr = np.zeros(1, np.int64)
        F = np.zeros((2, 1))
        FP = np.zeros((2, 1))
        ct = np.full(1, np.nan)
        cf = np.zeros(1)
        cfp = np.zeros(1)
        scratch = np.empty(SCRATCH)
        for row, t in enumerate((ta, tb)):
            eval_along(self.seg, hprim, self.rec, sarr, 1, (*self.o, *self.d), t,
                       (s.degree // 2, 1.0 / s.sigma**2, s.normalisation), scratch, F, FP, row, (ct, cf, cfp))
        return piece_bounds(self.rec, sarr, 1, F, FP, 0, 1, ta, tb, strict), (F[0, 0], F[1, 0])

    def describe(self):
        s = self.skel
        return (f"Skeleton({s.nodes.tolist()}, [[0, 1]], {s.radii.tolist()}, degree={s.degree}, "
                f"sigma={s.sigma}); o = {self.o.tolist()}, d = {self.d.tolist()}")


def _monotone_violations(f, sign, scale):
    """Indices i where f[i + 1] - f[i] goes against ``sign`` by more than NOISE * scale."""
    df = np.diff(f)
    return np.flatnonzero(sign * df < -NOISE * scale)


def arbitrate(ray, t, f, what):
    """The reference at ``t``, after checking that the compiled samples ``f``
    are within the compiled field's documented accuracy of it (so that a
    departure from monotonicity in ``f`` may be put down to rounding)."""
    fr = ray.exact(t)
    rel = REL16 if ray.skel.degree >= 16 else REL
    err = np.abs(f - fr)
    assert np.all(err <= rel * np.abs(fr) + 1e-14), (
        f"{what}: compiled field {f.tolist()} vs reference {fr.tolist()} at t = {t.tolist()}: "
        f"error {err.max()!r} beyond {rel:g} relative; {ray.describe()}")
    return fr


def assert_monotone(ray, t, f, sign, scale, what):
    """``f`` sampled at ``t`` is monotone in the direction ``sign`` (+1 up, -1
    down); departures beyond NOISE are re-examined with the reference."""
    for i in _monotone_violations(f, sign, scale)[:4]:
        w = np.arange(max(0, i - 3), min(len(t), i + 5))
        fr = arbitrate(ray, t[w], f[w], what)
        assert np.all(sign * np.diff(fr) >= -NOISE * scale), (
            f"{what}: the field is not monotone ({'up' if sign > 0 else 'down'}) near t = {t[i]!r}: "
            f"reference {fr.tolist()}; {ray.describe()}")


def assert_unimodal(ray, t, f, what):
    """Non-decreasing up to the largest sample, non-increasing after it."""
    fm = float(f.max())
    im = int(np.argmax(f))
    near = 4                                  # the peak's neighbourhood: noise decides the argmax there
    lo, hi = max(0, im - near), min(len(t), im + near + 1)
    assert_monotone(ray, t[:lo + 1], f[:lo + 1], +1, fm, what)
    assert_monotone(ray, t[hi - 1:], f[hi - 1:], -1, fm, what)
    def one_peak(v):
        k = int(np.argmax(v))
        return np.all(np.diff(v[:k + 1]) >= -NOISE * fm) and np.all(np.diff(v[k:]) <= NOISE * fm)

    if not one_peak(f[lo:hi]):
        fr = arbitrate(ray, t[lo:hi], f[lo:hi], what)
        assert one_peak(fr), (f"{what}: two maxima near the peak t = {t[im]!r}: reference {fr.tolist()}; "
                              f"{ray.describe()}")


def check_ray(ray: Ray, pieces=()):
    """Every property of the module docstring for one ray; ``pieces`` are
    extra fractions (u, v) of [t_in, t_out] delimiting pieces to test.
    Returns the field sampled on [t_in, t_out] (None for a miss)."""
    with serial():                  # many small batches: no thread-pool wake-up per call
        return _check_ray(ray, pieces)


def _check_ray(ray, pieces):
    L = ray.seg[0, 6]
    reach = L + 2 * ray.skel.sigma * ray.seg[0, 9]
    if not ray.hit:
        t = np.linspace(-reach, 2 * reach, DENSE)
        assert ray.field(t).max() == 0.0, f"ray_support missed a ray the field reaches; {ray.describe()}"
        return None
    tin, tout, tstar, fmax = (ray.rec[0, k] for k in (H_TIN, H_TOUT, H_TSTAR, H_FMAX))
    assert tin < tout
    # nothing of the field outside [t_in, t_out]
    outside = np.concatenate([np.linspace(tin - reach, tin, 400), np.linspace(tout, tout + reach, 400)])
    f_out = ray.field(outside)
    assert f_out.max() == 0.0, (f"field {f_out.max()!r} at t = {outside[np.argmax(f_out)]!r} outside "
                                f"[t_in, t_out] = [{tin!r}, {tout!r}]; {ray.describe()}")
    t = np.linspace(tin, tout, DENSE)
    f = ray.field(t)
    assert f.max() <= fmax, f"field {f.max()!r} above H_FMAX {fmax!r}; {ray.describe()}"
    if f.max() == 0.0:
        return f
    assert_unimodal(ray, t, f, "whole ray")
    cuts = [(tin, tstar), (tstar, tout), (tin, tout)]
    cuts += [(tin + u * (tout - tin), tin + (u + v * (1 - u)) * (tout - tin)) for u, v in pieces]
    for ta, tb in cuts:
        if not (tin <= ta < tb <= tout):
            continue
        check_piece(ray, ta, tb, float(f.max()))
    return f


def check_piece(ray, ta, tb, peak):
    tp = np.linspace(ta, tb, PIECE)
    fp = ray.field(tp)
    slack = 1e-9 * peak + 1e-300                   # the compiled field's own rounding
    for strict in (False, True):
        (lo, hi, mono), (f0, f1) = ray.piece(ta, tb, strict)
        what = f"piece [{ta!r}, {tb!r}] strict={strict}"
        assert fp.min() >= lo - slack and fp.max() <= hi + slack, (
            f"{what}: samples {fp.min()!r}..{fp.max()!r} outside the bounds [{lo!r}, {hi!r}]; {ray.describe()}")
        if strict:
            assert mono == 0
        elif mono:
            assert_monotone(ray, tp, fp, mono, peak, what + f" (called monotone {mono:+d})")
    K = lipschitz(ray.rec, 0, ta, tb)
    slope = np.abs(ray.slope(tp))
    assert slope.max() <= K * (1 + 1e-9) + 1e-12, (
        f"piece [{ta!r}, {tb!r}]: slope {slope.max()!r} above the Lipschitz bound {K!r}; {ray.describe()}")


# ----------------------------------------------------------------------------- random rays
def _unit(v):
    return v / np.linalg.norm(v)


def _direction(z, phi):
    s = math.sqrt(max(0.0, 1.0 - z * z))
    return np.array([s * math.cos(phi), s * math.sin(phi), z])


FAMILIES = ["general", "nested", "critical_E", "critical_A", "axis", "thin_tip"]


@st.composite
def rays(draw):
    """A segment (taper ratio 1..1e4, optionally nested or critical) and a ray
    through (or near) its support."""
    family = draw(st.sampled_from(FAMILIES))
    degree = draw(st.sampled_from([2, 4, 6, 8, 16]))
    sigma = draw(st.sampled_from([1.25, 2.0, 3.0]))
    r1 = 10 ** draw(st.floats(-1.3, 0.0))
    ratio = 10 ** draw(st.floats(0.0, 4.0))
    r0 = r1 / ratio
    if family == "nested":                                   # sigma (r1 - r0) > L
        L = sigma * (r1 - r0) * draw(st.floats(0.05, 0.999))
    elif family == "critical_E":                             # L = sigma (r1 - r0), to rounding
        L = sigma * (r1 - r0) * (1 + draw(st.sampled_from([0.0, 1e-15, -1e-15, 1e-9, -1e-9])))
    else:
        L = 10 ** draw(st.floats(-1.3, 0.7))
        if family == "critical_A" and not sigma * (r1 - r0) < 0.95 * L:
            L = sigma * (r1 - r0) * draw(st.floats(1.05, 20.0))
    if not L > 1e-4 * r1:
        L = 1e-4 * r1 + sigma * (r1 - r0)
    u = _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi)))
    a = np.array([draw(st.floats(-1, 1)) for _ in range(3)])
    b = a + L * u
    flip = draw(st.booleans())
    skel = Skeleton([b, a] if flip else [a, b], [[0, 1]], [[r1, r0]] if flip else [[r0, r1]], degree, sigma)
    seg = segment_table(skel)
    A0, U, Ls, dtau = seg[0, 0:3], seg[0, 3:6], seg[0, 6], seg[0, 8] * seg[0, 6]
    side = _unit(np.cross(U, _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi))) + 1e-3))
    if family == "critical_A":
        # sin(angle to the axis) = sigma dtau / L: A = |D|^2 - (D.d)^2 - sigma^2 dtau^2 = 0
        sn = sigma * dtau / Ls * (1 + draw(st.sampled_from([0.0, 1e-14, -1e-14, 1e-8, -1e-8, 1e-4, -1e-4])))
        d = math.sqrt(1 - sn * sn) * U + sn * side
    elif family == "axis":
        d = _unit(U + draw(st.sampled_from([0.0, 1e-9, 1e-4, 1e-2])) * side)
    else:
        d = _direction(draw(st.floats(-1, 1)), draw(st.floats(0, 2 * math.pi)))
    if draw(st.booleans()):
        d = -d
    s = 0.0 if family == "thin_tip" else draw(st.floats(-0.1, 1.1))
    tau = seg[0, 7] + dtau * min(max(s, 0.0), 1.0)
    off = _unit(np.cross(d, side) + 1e-3 * side) * sigma * tau * draw(st.floats(0.0, 1.1))
    q = A0 + s * Ls * U + off
    o = q - (Ls + 2 * sigma * seg[0, 9]) * d
    pieces = draw(st.lists(st.tuples(st.floats(0, 1), st.floats(0.001, 1)), min_size=2, max_size=4))
    return family, Ray(skel, o, d), pieces


@settings(max_examples=400, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(rays())
def test_one_segment_on_any_ray(case):
    family, ray, pieces = case
    check_ray(ray, pieces)


# ----------------------------------------------------------------------------- named cases
def _critical_a_ray(r0, r1, L, sigma, off, tilt=1.0):
    """A segment along z and a ray in the xz plane at the critical angle
    (sin = sigma (r1 - r0) / L): the ray is parallel to one generator of the
    support cone, A = 0 to rounding."""
    skel = Skeleton([[0, 0, 0], [0, 0, L]], [[0, 1]], [[r0, r1]], 6, sigma)
    sn = sigma * (r1 - r0) / L * tilt
    d = np.array([sn, 0.0, math.sqrt(1 - sn * sn)])
    q = np.array([off, 0.03, 0.5 * L])
    return Ray(skel, q - 3 * L * d, d)


@pytest.mark.parametrize("off", [0.0, 0.05, -0.05, -0.2])
def test_ray_along_a_support_cone_generator_enters_where_the_field_starts(off):
    """Regression: with A = 0 to rounding the textbook quadratic formula for the
    entry's stationary point cancelled to s = 0, and t_in came out up to
    0.09 mm (a third of the radius) late while the field there reached 0.18:
    the tracer and the renderer ignored that part of the primitive."""
    ray = _critical_a_ray(0.1, 0.3, 1.0, 2.0, off)
    assert ray.hit
    t = np.linspace(ray.rec[0, H_TIN] - 1.0, ray.rec[0, H_TIN], 20001)
    assert ray.field(t).max() == 0.0
    check_ray(ray, [(0.1, 0.2), (0.5, 0.5)])


NAMED = {
    # E = 0 exactly (dyadic): L = sigma (r1 - r0), the thin end ball touches the thick one inside
    "E0_oblique": (Skeleton([[0, 0, 0], [0, 0, 1.0]], [[0, 1]], [[0.25, 0.75]]), [0.3, 0.1, 0.2], [1, 0.5, 0.25]),
    "E0_axis": (Skeleton([[0, 0, 0], [0, 0, 1.0]], [[0, 1]], [[0.25, 0.75]]), [0.1, 0.05, -3.0], [0, 0, 1]),
    "E0_across": (Skeleton([[0, 0, 0], [0, 0, 1.0]], [[0, 1]], [[0.25, 0.75]]), [-3.0, 0.02, 0.1], [1, 0, 0]),
    # nested end balls: the support is the thick end's ball
    "nested": (Skeleton([[0, 0, 0], [0.2, 0.1, 0.3]], [[0, 1]], [[0.1, 1.0]]), [-3.0, 0.3, 0.2], [1, -0.1, 0.05]),
    # taper ratio 1e4: along the axis from the thin tip, and grazing the tip
    "ratio_1e4_axis": (Skeleton([[0, 0, 0], [0, 0, 2.0]], [[0, 1]], [[1e-4, 1.0]]), [0, 0, -3.0], [0, 0, 1]),
    "ratio_1e4_tip": (Skeleton([[0, 0, 0], [0, 0, 2.0]], [[0, 1]], [[1e-4, 1.0]]), [-3.0, 0, 1e-4], [1, 0, 0]),
    "ratio_1e4_reverse": (Skeleton([[0, 0, 2.0], [0, 0, 0]], [[0, 1]], [[1.0, 1e-4]]), [0.01, 0, 5.0], [0, 0, -1]),
    # constant radius, ray exactly along the axis (the field is flat in the middle)
    "cylinder_axis": (Skeleton([[0, 0, 0], [0, 0, 4.0]], [[0, 1]], [[0.5, 0.5]]), [0, 0, -2.0], [0, 0, 1]),
}


@pytest.mark.parametrize("name", sorted(NAMED))
def test_named_stiff_rays(name):
    skel, o, d = NAMED[name]
    ray = Ray(skel, o, _unit(np.asarray(d, float)))
    assert ray.hit
    f = check_ray(ray, [(0.0, 0.01), (0.02, 0.1), (0.45, 0.1), (0.9, 1.0)])
    assert f.max() > 0.0


@pytest.mark.parametrize("tilt", [1.0, 1 + 1e-12, 1 - 1e-12, 1 + 1e-6, 1 - 1e-6])
@pytest.mark.parametrize("ratio", [1.5, 3.0, 100.0, 1e4])
def test_critical_a_over_tapers(ratio, tilt):
    r1 = 0.4
    r0 = r1 / ratio
    ray = _critical_a_ray(r0, r1, 2.0, 2.0, -0.5 * r1, tilt)
    check_ray(ray, [(0.05, 0.1), (0.3, 0.4)])
