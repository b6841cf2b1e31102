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
field (the checks: ``check_ray`` in tests/helpers.py):

* the field is zero outside ``[t_in, t_out]`` (a miss is a real miss), to the compiled
  field's absolute accuracy (``FIELD_ZERO``, 1e-14: a ray tangent to a support gets
  values of about 1e-23 from the closed form, and from the reference too);
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

from helpers import Ray, _unit, check_ray, rays
from slicer import Skeleton
from slicer._kernels.rays.support import H_TIN


@settings(max_examples=400, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(rays())
def test_one_segment_on_any_ray(case):
    family, ray, pieces = case
    check_ray(ray, pieces)


# ----------------------------------------------------------------------------- named cases
#: rays tangent to a degree-2 support (found by the property test above on one run): the
#: closed form and the reference give 1e-24 to 1e-22 there, zero only to rounding
TANGENT = [
    ([[0.0, 0.0, 0.0], [0.5403023058681398, 0.8414709848078965, 0.0]],
     [-2.942894283863719, -2.26977218107918, -0.0027349591058476483], [0.5403023058681398, 0.8414709848078965, 0.0]),
    ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [-3.5, -0.8847669175763194, -0.8829991515072357], [1.0, 0.0, 0.0]),
    ([[0.0, 1.0, 0.0], [0.05403023058681398, 1.0841470984807897, 0.0]],
     [-2.4566222085823926, -0.5124482947520741, -0.0027349591058476483], [0.5403023058681394, 0.8414709848078966, 0.0]),
    ([[0.0, -1.0, 0.0], [0.9689124217106447, -0.752596040745477, 0.0]],
     [-3.700444475783395, -0.6547887968550987, -0.006317188251823857], [0.9689124217106448, 0.247403959254523, 0.0]),
]


@pytest.mark.parametrize("nodes, o, d", TANGENT)
def test_rays_tangent_to_a_support(nodes, o, d):
    ray = Ray(Skeleton(nodes, [[0, 1]], [[1.0, 1.0]], degree=2, sigma=1.25), o, d)
    check_ray(ray, [(0.0, 1.0)])
    t = np.linspace(-10.0, 10.0, 2001)
    assert ray.field(t).max() < 1e-20            # the field stays at rounding level along the whole ray


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
