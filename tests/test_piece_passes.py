"""The disc and crest bounds' piece passes (ends, terms on vector lanes, sums in
order) give the bounds of one plain loop over the pieces, to the bit.

The references below are that loop, written out in Python from the formulas of
docs/math.md §10 and §10.1 with the same operations in the same order (Python
floats round as the compiled code does: no fused multiply-add, no fast-math).
"""
from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from slicer import Skeleton
from slicer._kernels.contours import cellbounds as cb
from slicer._kernels.contours import ridgebounds as rb
from slicer._kernels.field.segment import AX, AY, AZ, DELTA, LEN, TAU0, UX, UY, UZ
from slicer._kernels.rays.support import kprime_max
from slicer.model.field import point_grid

SLACK = cb.SLACK
_ipow = cb._ipow.py_func
_slope_sup = cb._slope_sup.py_func
_curvature_sup = cb._curvature_sup.py_func
_second_sup = cb._second_sup.py_func
_radial = cb._radial.py_func


def _dist2(w, u, t):
    x, y, z = w[0] - t * u[0], w[1] - t * u[1], w[2] - t * u[2]
    q = x * x + y * y
    return q, q + z * z


def one_loop_piece_bounds(seg, i, cx, cy, cz, r, ta, tb, n, sigma, norm, k1, k2, pieces):
    """``_piece_bounds`` as one loop over the pieces, each piece's end shared with the next."""
    w = (cx - seg[i, AX], cy - seg[i, AY], cz - seg[i, AZ])
    u = (seg[i, UX], seg[i, UY], seg[i, UZ])
    wu = w[0] * u[0] + w[1] * u[1] + w[2] * u[2]
    tau0, d = seg[i, TAU0], seg[i, DELTA]
    m = n // 2
    inv_s2 = 1.0 / (sigma * sigma)
    cn = norm * n * inv_s2
    step = (tb - ta) / pieces
    g = h = f = bh = bl = a = ru = rl = 0.0
    rho_c = math.sqrt(max(w[0] * w[0] + w[1] * w[1] + w[2] * w[2] - wu * wu, 0.0))
    rho = rho_c * (1.0 + SLACK) + r
    # the radial terms of an untapered segment: kappa = 2(m - 1) rho_p^2 / (sigma tau)^2 - 1 over the disc
    S2 = (sigma * tau0) * (sigma * tau0)
    S2 = S2 if S2 > 0.0 else 1.0
    rho_lo = max(rho_c * (1.0 - SLACK) - r, 0.0)
    kap_lo = 2.0 * (m - 1.0) * rho_lo * rho_lo / S2 * (1.0 - SLACK) - 1.0
    kap_hi = 2.0 * (m - 1.0) * rho * rho / S2 * (1.0 + SLACK) - 1.0
    ustar = (1.0 - (m - 2.0) * kap_hi) / (m - 1.0) if m >= 2 else 1.0
    q0, Q0 = _dist2(w, u, ta + 0 * step)
    D0 = math.sqrt(Q0)
    ita = 1.0 / (tau0 + d * (ta + 0 * step))
    for j in range(pieces):
        t0 = ta + j * step
        t1 = tb if j == pieces - 1 else ta + (j + 1) * step
        if not tau0 + d * t0 > 0.0:
            return math.inf, math.inf, math.inf, math.inf, 0.0, math.inf, math.inf, -math.inf, 0.0, 0.0
        q1, Q1 = _dist2(w, u, t1)
        D1 = math.sqrt(Q1)
        dist = D0 if wu <= t0 else (D1 if wu >= t1 else math.sqrt(_dist2(w, u, wu)[1]))
        dmax, qmax = max(D0, D1), max(q0, q1)
        q0, D0 = q1, D1
        dlo = dist * (1.0 - SLACK) - r
        it, ith = ita, 1.0 / (tau0 + d * t1)
        ita = ith
        s_lo = max(dlo, 0.0) * ith * (1.0 - SLACK)
        if s_lo >= sigma:
            continue
        pe = 1.0
        if dlo > 0.0:
            pe = min(1.0, (math.sqrt(qmax) * (1.0 + SLACK) + r) * (1.0 / dlo))
        s_hi = (dmax * (1.0 + SLACK) + r) * it * (1.0 + SLACK)
        ln = t1 - t0
        it3 = it * it * it
        u_lo = s_lo * s_lo * inv_s2
        ww = 1.0 - u_lo
        w1 = _ipow(ww, m - 1)
        g += ln * pe * _slope_sup(s_lo, w1, n, sigma, cn, k1) * it * it
        h += ln * _curvature_sup(u_lo, w1, m, cn, k2) * it3
        f += ln * norm * w1 * ww * it
        if m >= 2:
            u_hi = min(s_hi * s_hi * inv_s2, 1.0)
            bh += ln * cn * w1 * it3
            bl += ln * cn * _ipow(1.0 - u_hi, m - 1) * (ith * ith * ith)
            a += ln * cn * _second_sup(u_lo, u_hi, m) * it3 * pe * pe
            least = min(_radial(u_lo, kap_lo, m), _radial(u_hi, kap_lo, m))
            uc = min(max(3.0 / (2.0 * m - 1.0), u_lo), u_hi)
            top = min(_radial(min(max(ustar, u_lo), u_hi), kap_hi, m), _radial(uc, 2.0 * (m - 1.0) * uc - 1.0, m))
            if s_hi >= sigma:
                least = min(least, 0.0)
                top = max(top, 0.0)
            ru += ln * cn * top * it3
            rl += ln * cn * least * it3
    if m < 2:
        bh = math.inf
    zm, zn = cb._cross_reach.py_func(w[0], w[1], w[2], u[0], u[1], u[2], wu, rho_c, r)
    return g, h, f, bh, bl, a, ru, rl, zm, zn


def _across(cw, aw, nw, t0, t1, r, dlo):
    top = max(abs(cw - t0 * aw), abs(cw - t1 * aw)) * (1.0 + SLACK) + r * nw
    return min(nw, top / dlo) if dlo > 0.0 else nw


def one_loop_frame_sums(seg, i, cx, cy, cz, r, ta, tb, ux, uy, n, sigma, norm):
    """The piece sums of ``_segment_frame`` as one loop: ``(guu, gvv, guv, tuu, tvv, tuv, bl, bh)``,
    or None where a piece starts at a radius that is not positive."""
    w = (cx - seg[i, AX], cy - seg[i, AY], cz - seg[i, AZ])
    ax, ay, az = seg[i, UX], seg[i, UY], seg[i, UZ]
    tau0, d = seg[i, TAU0], seg[i, DELTA]
    vx, vy = -uy, ux
    ua, va = ux * ax + uy * ay, vx * ax + vy * ay
    upx, upy, upz = ux - ua * ax, uy - ua * ay, -ua * az
    vpx, vpy, vpz = vx - va * ax, vy - va * ay, -va * az
    nu = math.sqrt(upx * upx + upy * upy + upz * upz)
    nv = math.sqrt(vpx * vpx + vpy * vpy + vpz * vpz)
    cu, cv = w[0] * ux + w[1] * uy, w[0] * vx + w[1] * vy
    cup, cvp = w[0] * upx + w[1] * upy + w[2] * upz, w[0] * vpx + w[1] * vpy + w[2] * vpz
    m = n // 2
    cn = norm * n / (sigma * sigma)
    P = rb.PIECES
    step = (tb - ta) / P
    sums = [0.0] * 8
    for j in range(P):
        t0 = ta + j * step
        t1 = tb if j == P - 1 else ta + (j + 1) * step
        tau_lo, tau_hi = tau0 + d * t0, tau0 + d * t1
        if not tau_lo > 0.0:
            return None
        tc = min(max(w[0] * ax + w[1] * ay + w[2] * az, t0), t1)
        dist = math.sqrt(_dist2(w, (ax, ay, az), tc)[1])
        dmax = math.sqrt(max(_dist2(w, (ax, ay, az), t0)[1], _dist2(w, (ax, ay, az), t1)[1]))
        dlo = dist * (1.0 - SLACK) - r
        ith = 1.0 / tau_hi
        s_lo = max(dlo, 0.0) * ith * (1.0 - SLACK)
        if s_lo >= sigma:
            continue
        it = 1.0 / tau_lo
        s_hi = (dmax * (1.0 + SLACK) + r) * it * (1.0 + SLACK)
        inv_s2 = 1.0 / (sigma * sigma)
        u_lo, u_hi = s_lo * s_lo * inv_s2, min(s_hi * s_hi * inv_s2, 1.0)
        ln = (t1 - t0) * cn
        it3 = it * it * it
        sec = ln * _second_sup(u_lo, u_hi, m) * it3
        sums[6] += ln * _ipow(1.0 - u_hi, m - 1) * (ith * ith * ith)
        sums[7] += ln * _ipow(1.0 - u_lo, m - 1) * it3
        pu, pv = _across(cu, ua, 1.0, t0, t1, r, dlo), _across(cv, va, 1.0, t0, t1, r, dlo)
        sums[0] += sec * pu * pu
        sums[1] += sec * pv * pv
        sums[2] += sec * pu * pv
        if d == 0.0:
            pu, pv = _across(cup, 0.0, nu, t0, t1, r, dlo), _across(cvp, 0.0, nv, t0, t1, r, dlo)
            sums[3] += sec * pu * pu
            sums[4] += sec * pv * pv
            sums[5] += sec * pu * pv
    return sums


def _near(seg, i, sigma, rng):
    """A point within the support of segment ``i`` (a random axis point, moved less than its support radius)."""
    t = rng.uniform(0.0, seg[i, LEN])
    off = rng.normal(size=3)
    off *= rng.uniform(0.0, 0.95) * sigma * (seg[i, TAU0] + seg[i, DELTA] * t) / np.linalg.norm(off)
    return [seg[i, c] + t * seg[i, u] + o for c, u, o in zip((AX, AY, AZ), (UX, UY, UZ), off)]


def _scene(seed, degree, tapered):
    rng = np.random.default_rng(seed)
    nodes = rng.uniform(0.0, 3.0, (6, 3))
    segs = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 0], [0, 3]])
    radii = rng.uniform(0.05, 0.5, (segs.shape[0], 2))
    if not tapered:
        radii[:, 1] = radii[:, 0]
    s = Skeleton(nodes, segs, radii, degree=degree)
    return s, point_grid(s)[0], rng


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), degree=st.sampled_from([2, 4, 6, 8]), tapered=st.booleans(),
       pieces=st.sampled_from([1, 4, 9, 32]))
def test_piece_bounds_are_one_loop_over_the_pieces_to_the_bit(seed, degree, tapered, pieces):
    s, seg, rng = _scene(seed, degree, tapered)
    k1 = kprime_max(s.degree, s.sigma, s.normalisation)
    k2 = cb.kernel_curvature_max(s.degree, s.sigma, s.normalisation)
    work = np.full(cb.disc_work(pieces), np.nan)
    reached = 0
    for _ in range(30):
        i = int(rng.integers(seg.shape[0]))
        # a disc centred in the support (it reaches it), or anywhere (it may reach only with its radius)
        cx, cy, cz = _near(seg, i, s.sigma, rng) if rng.random() < 0.7 else rng.uniform(0.0, 3.0, 3)
        r = 10.0 ** rng.uniform(-4, 0)
        ta, tb = cb._reach_interval(seg, i, cx, cy, cz, r, s.sigma)
        if not tb > ta:
            continue
        reached += 1
        got = cb._piece_bounds(seg, i, cx, cy, cz, r, ta, tb, s.degree, s.sigma, s.normalisation, k1, k2, pieces,
                               work)
        want = one_loop_piece_bounds(seg, i, cx, cy, cz, r, ta, tb, s.degree, s.sigma, s.normalisation, k1, k2,
                                     pieces)
        assert np.array_equal(np.array(got), np.array(want), equal_nan=True), (got, want)
    assert reached > 0


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), degree=st.sampled_from([4, 6, 8]), tapered=st.booleans(),
       lying=st.booleans())
def test_crest_piece_sums_are_one_loop_over_the_pieces_to_the_bit(seed, degree, tapered, lying):
    s, seg, rng = _scene(seed, degree, tapered)
    if lying:                                   # struts lying in the plane z = 1.5: crests
        s, seg, rng = _scene(seed, degree, tapered)
        nodes = s.nodes.copy()
        nodes[:, 2] = 1.5
        s = Skeleton(nodes, s.segments, s.radii, degree=degree)
        seg = point_grid(s)[0]
    k1 = kprime_max(s.degree, s.sigma, s.normalisation)
    work = np.full(rb.FRAME_WORK, np.nan)
    reached = 0
    for _ in range(30):
        i = int(rng.integers(seg.shape[0]))
        cx, cy, cz = _near(seg, i, s.sigma, rng) if rng.random() < 0.7 else rng.uniform(0.0, 3.0, 3)
        if lying:
            cz = 1.5
        r = 10.0 ** rng.uniform(-4, 0)
        phi = rng.uniform(0.0, 2.0 * math.pi)
        ux, uy = math.cos(phi), math.sin(phi)
        ta, tb = cb._reach_interval(seg, i, cx, cy, cz, r, s.sigma)
        if not tb > ta:
            continue
        reached += 1
        got = rb._segment_frame(seg, i, cx, cy, cz, r, ta, tb, ux, uy, s.degree, s.sigma, s.normalisation, k1, work)
        sums = one_loop_frame_sums(seg, i, cx, cy, cz, r, ta, tb, ux, uy, s.degree, s.sigma, s.normalisation)
        if sums is None:
            assert got == (math.inf, math.inf, math.inf, math.inf)
            continue
        guu, gvv, guv, tuu, tvv, tuv, bl, bh = sums
        fuu, fvv, fuv, mag = guu - bl, gvv - bl, guv, guu + gvv + guv + bh
        if seg[i, DELTA] == 0.0:
            W = cb._end_slopes(seg, i, cx, cy, cz, r, s.degree, s.sigma, s.normalisation, k1)
            ua = abs(ux * seg[i, UX] + uy * seg[i, UY])
            va = abs(-uy * seg[i, UX] + ux * seg[i, UY])
            upx, upy, upz = (ux - (ux * seg[i, UX] + uy * seg[i, UY]) * seg[i, UX],
                             uy - (ux * seg[i, UX] + uy * seg[i, UY]) * seg[i, UY],
                             -(ux * seg[i, UX] + uy * seg[i, UY]) * seg[i, UZ])
            vpx, vpy, vpz = (-uy - (-uy * seg[i, UX] + ux * seg[i, UY]) * seg[i, UX],
                             ux - (-uy * seg[i, UX] + ux * seg[i, UY]) * seg[i, UY],
                             -(-uy * seg[i, UX] + ux * seg[i, UY]) * seg[i, UZ])
            nu = math.sqrt(upx * upx + upy * upy + upz * upz)
            nv = math.sqrt(vpx * vpx + vpy * vpy + vpz * vpz)
            fuu = min(fuu, tuu - bl * nu * nu + ua * (ua + 2.0 * nu) * W)
            fvv = min(fvv, tvv - bl * nv * nv + va * (va + 2.0 * nv) * W)
            fuv = min(fuv, tuv + abs(upx * vpx + upy * vpy + upz * vpz) * bh + (ua + va * nu) * W)
            mag += tuu + tvv + tuv + 3.0 * W
        assert np.array_equal(np.array(got), np.array([fvv, fuu, fuv, mag]), equal_nan=True), (got, sums)
    assert reached > 0
