"""The compiled cell-state passes against whole-array numpy references.

``slicer._kernels.cellstate`` replaced a few dozen numpy steps each: the
states, curvature and slope bounds must be the same floats, including where
bounds are infinite or NaN (no support, degree 2) and gradients vanish.
"""
from __future__ import annotations

import numpy as np
import pytest

from slicer._kernels.cellstate import IN, ONEDIR, OUT, SIMPLE, crest_candidates, judge_cells, settle_from_parent

SLACK = 1e-9


def judge_reference(f, g, G, H, far, r, tol, slack):
    gx, gy = g[:, 0], g[:, 1]
    gn = np.hypot(gx, gy)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        spread = r * np.minimum(G, gn + 0.5 * r * H)
        spread = np.where(np.isnan(spread), np.inf, spread)
        fs = slack * (1.0 + np.abs(f))
        gs = slack * (gn + G) + r * H
        gs = np.where(np.isnan(gs), np.inf, gs)
        state = np.full(f.size, -1, np.int8)
        state[(f + spread + fs < 1.0) | far] = OUT
        state[f - spread - fs > 1.0] = IN
        mx = np.abs(gx) > gs
        my = np.abs(gy) > gs
        state[(state < 0) & mx & my] = SIMPLE
        gmin = np.maximum(np.abs(gx), np.abs(gy)) - gs
        cap = H * r * r / (4.0 * gmin)
        state[(state < 0) & (mx | my) & (gmin > 0) & (cap <= 0.5 * tol)] = ONEDIR
        glo = gn - gs
        kappa = np.where(glo > 0, H / np.where(glo > 0, glo, 1.0), np.inf)
        slope = np.maximum(np.column_stack([np.abs(gx), np.abs(gy)]) - gs[:, None], 0.0)
    slope[~np.isfinite(slope)] = 0.0
    return state, kappa, slope


def random_cells(seed, k=4000):
    """Cells near the contour (f close to 1, partials of either size) with a
    share of infinite and NaN bounds and zero gradients."""
    rng = np.random.default_rng(seed)
    f = 1.0 + rng.normal(0, 0.05, k) * rng.choice([0.01, 1.0, 10.0], k)
    g = rng.normal(0, 5.0, (k, 2)) * rng.choice([0.0, 0.01, 1.0], (k, 2))
    G = np.abs(rng.normal(0, 10.0, k)) + np.hypot(g[:, 0], g[:, 1])
    H = np.abs(rng.normal(0, 200.0, k))
    r = rng.choice([1e-4, 1e-3, 1e-2, 0.05], k)
    G[rng.random(k) < 0.05] = np.inf
    H[rng.random(k) < 0.05] = np.inf
    H[rng.random(k) < 0.02] = np.nan
    far = rng.random(k) < 0.1
    return f, np.ascontiguousarray(g), G, H, far, r


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_judge_cells_matches_the_numpy_steps(seed):
    f, g, G, H, far, r = random_cells(seed)
    got = judge_cells(f, g, G, H, far, r, 1e-3, SLACK)
    want = judge_reference(f, g, G, H, far, r, 1e-3, SLACK)
    for a, b in zip(got, want):
        assert np.array_equal(a, b)
    # every state occurs, so each branch was compared
    assert set(np.unique(got[0]).tolist()) == {-1, OUT, IN, SIMPLE, ONEDIR}


@pytest.mark.parametrize("seed", [0, 1])
def test_settle_from_parent_matches_the_numpy_steps(seed):
    f, g, G, H, _, _ = random_cells(seed, 1000)
    rng = np.random.default_rng(seed + 10)
    r = 0.01
    pcx, pcy = rng.uniform(-5, 5, f.size), rng.uniform(-5, 5, f.size)
    # four children per parent, in parent order, each within the parent's cell
    cx = np.repeat(pcx, 4) + np.tile([-0.5, 0.5, -0.5, 0.5], f.size) * r
    cy = np.repeat(pcy, 4) + np.tile([-0.5, -0.5, 0.5, 0.5], f.size) * r
    F, Gr, GG, HH = (np.repeat(a, 4, axis=0) for a in (f, g, G, H))
    offset = np.column_stack([cx - np.repeat(pcx, 4), cy - np.repeat(pcy, 4)])
    gn = np.hypot(Gr[:, 0], Gr[:, 1])
    with np.errstate(invalid="ignore", over="ignore"):
        lin = F + Gr[:, 0] * offset[:, 0] + Gr[:, 1] * offset[:, 1]
        spread = r * gn + 2.0 * HH * r * r
        slack = SLACK * (1.0 + np.abs(F) + 2.0 * r * (gn + GG))
    want = np.full(F.size, -1, np.int8)
    want[lin + spread + slack < 1.0] = OUT
    want[lin - spread - slack > 1.0] = IN
    got = settle_from_parent(f, g, G, H, r, cx, cy, (pcx, pcy), SLACK)
    assert np.array_equal(got, want)
    assert set(np.unique(got).tolist()) == {-1, OUT, IN}


@pytest.mark.parametrize("seed", [0, 1])
def test_crest_candidates_match_the_numpy_steps(seed):
    f, g, G, H, far, r = random_cells(seed)
    state = judge_cells(f, g, G, H, far, r, 1e-3, SLACK)[0]
    rr, thin = 0.01, 2.5e-4
    gn = np.hypot(g[:, 0], g[:, 1])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        t = np.minimum(gn / H, rr)
        low = f + gn * t - 0.5 * H * t * t - SLACK * (1.0 + np.abs(f) + rr * (gn + G))
        want = (state < 0) & (gn <= rr * H * (1.0 + 1e-9) + SLACK * (gn + G)) & ~(low > 1.0 + 0.125 * H * thin ** 2)
    got = crest_candidates(state, f, g, G, H, rr, thin, SLACK, 1e-9)
    assert np.array_equal(got, want)
    assert got.any() and not got.all()
