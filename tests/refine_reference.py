"""The contours' root solver, projections and chord refinement as they were
written before they became compiled kernels: whole-array numpy steps, every
unfinished segment or chord of a round at once. Naive references for
:func:`slicer._kernels.contours.crossings.solve_segments`,
:func:`slicer._kernels.contours.crossings.project_points` and
:func:`slicer._kernels.contours.refine.refine_chords` (bit for bit, evaluation counts
included; tests/test_refine.py). The bracket steps are plain Python loops."""
from __future__ import annotations

import numpy as np

from slicer.contours.roots import FIELD_SLACK, MAX_ITER, _field
from slicer.contours.simplify import CHORD_FRACTION
from slicer.model.skeleton import Skeleton


def np_minimum(a, b):
    """``np.minimum`` of two floats: NaN if either is NaN."""
    if a != a or b != b:
        return np.nan
    return a if a <= b else b


def np_maximum(a, b):
    """``np.maximum`` of two floats: NaN if either is NaN."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


def bracket_points(act, br, tol_t, it, a, d):
    """The next point of each open segment: the secant point of its bracket
    kept ``tol_t / 2`` inside it, or the middle when two steps failed to halve
    the bracket (``it > 2``) or the secant point is not strictly inside.
    Shifts the bracket widths of the last two steps.

    Parameters
    ----------
    act : (k,) int64
        Open segments.
    br : tuple
        The solver's arrays (module docstring).
    tol_t : (n,) float64
        Tolerance as a fraction of each segment.
    it : int
        Iteration, from 1.
    a, d : (n, 3) float64, mm
        Segment starts and directions (``b − a``).

    Returns
    -------
    tm : (k,) float64
    points : (k, 3) float64, mm
    """
    lo, hi, glo, ghi, _, width1, width2, _, _, _ = br
    k = act.shape[0]
    tm = np.empty(k)
    pts = np.empty((k, 3))
    for j in range(k):
        i = act[j]
        l = lo[i]
        h = hi[i]
        gl = glo[i]
        w = h - l
        q = 0.5 * tol_t[i]
        ts = l + w * gl / (gl - ghi[i])           # gl >= 0 > gh: a point of [l, h]
        # tol/2 inside the bracket: near the root, the next step then lands on
        # the other side and closes the bracket to about tol
        ts = np_minimum(np_maximum(ts, l + q), h - q)
        if (w > 0.5 * width2[i] and it > 2) or not ts > l or not ts < h:
            ts = 0.5 * (l + h)
        width2[i] = width1[i]
        width1[i] = w
        tm[j] = ts
        for c in range(3):
            pts[j, c] = a[i, c] + ts * d[i, c]
    return tm, pts


def bracket_update(act, tm, f, br, reach_t, length, tol, slack):
    """Narrow each open segment's bracket with the value ``f`` at ``tm``
    (Illinois: the stale end's value is halved when the same end moves
    twice), and with a slope bound (``reach_t`` finite: 1 / (slope × length))
    the interval the values prove the root in. A segment is finished when the
    value is exactly 1 or the bracket is at most ``tol`` long (``t``: the
    secant point of the final bracket), or when the proven interval is
    (``t``: its middle).

    Returns
    -------
    (k',) int64
        The segments still open.
    """
    lo, hi, glo, ghi, side, _, _, clo, chi, t = br
    k = act.shape[0]
    keep = np.empty(k, np.int64)
    nk = 0
    for j in range(k):
        i = act[j]
        m = tm[j]
        g = f[j] - 1.0
        up = g >= 0.0
        gl, gh = glo[i], ghi[i]
        if up:
            if side[i] == 1:
                gh = 0.5 * gh
            lo[i], glo[i], ghi[i], side[i] = m, g, gh, 1
        else:
            if side[i] == -1:
                gl = 0.5 * gl
            glo[i], hi[i], ghi[i], side[i] = gl, m, g, -1
        t[i] = m
        e = (abs(g) + slack * (1.0 + abs(f[j]))) * reach_t[i]
        chi[i] = np_minimum(chi[i], m + e if up else m)
        clo[i] = np_maximum(clo[i], m if up else m - e)
        lo2, hi2 = lo[i], hi[i]
        pr = (np_minimum(chi[i], hi2) - np_maximum(clo[i], lo2)) * length[i] <= tol
        exact = g == 0.0
        done = exact or (hi2 - lo2) * length[i] <= tol
        if pr and not done:
            t[i] = 0.5 * (np_minimum(chi[i], hi2) + np_maximum(clo[i], lo2))
        if done and not exact:
            # secant point of the final bracket (Illinois-scaled values keep their signs)
            ts = lo2 + (hi2 - lo2) * glo[i] / (glo[i] - ghi[i])
            t[i] = np_minimum(np_maximum(ts, lo2), hi2)
        if not (done or pr):
            keep[nk] = i
            nk += 1
    return keep[:nk].copy()

def solve_crossings(skel: Skeleton, a: np.ndarray, b: np.ndarray, tol: float,
                    fa: np.ndarray | None = None, fb: np.ndarray | None = None,
                    slope: np.ndarray | None = None):
    """The batch solver of :func:`slicer.contours.roots.solve_crossings`:
    every unfinished segment evaluated at once per step."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    n = a.shape[0]
    evals = 0
    if fa is None:
        fa = _field(skel, a)[0]
        evals += n
    if fb is None:
        fb = _field(skel, b)[0]
        evals += n
    d = b - a
    length = np.sqrt((d * d).sum(axis=1))
    glo = fa - 1.0
    ghi = fb - 1.0
    bracketed = (glo >= 0.0) & (ghi < 0.0)
    lo = np.zeros(n)
    hi = np.ones(n)
    t = np.where(np.abs(glo) <= np.abs(ghi), 0.0, 1.0)
    side = np.zeros(n, np.int8)          # last end moved: +1 lo, -1 hi
    with np.errstate(divide="ignore"):
        tol_t = np.where(length > 0, tol / length, 1.0)
    width1 = hi - lo                      # bracket width one and two steps ago
    width2 = hi - lo
    # interval proved by the slope bound, in t; (clo, chi) = (0, 1) without one
    clo = np.zeros(n)
    chi = np.ones(n)
    if slope is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            reach_t = np.where((slope > 0) & (length > 0), 1.0 / (slope * length), np.inf)
        ea = (np.abs(glo) + FIELD_SLACK * (1.0 + np.abs(fa))) * reach_t
        eb = (np.abs(ghi) + FIELD_SLACK * (1.0 + np.abs(fb))) * reach_t
        chi = np.minimum(chi, ea)
        clo = np.maximum(clo, 1.0 - eb)
    proved = bracketed & ((chi - clo) * length <= tol)
    act = np.flatnonzero(bracketed & (length > tol) & ~proved)
    t[bracketed] = np.where(glo[bracketed] == 0.0, 0.0, 0.5)
    pf = np.flatnonzero(proved & (length > tol) & (glo != 0.0))
    t[pf] = 0.5 * (clo[pf] + chi[pf])
    if slope is None:
        reach_t = np.full(n, np.inf)        # proves nothing: (clo, chi) stay (0, 1)
    br = (lo, hi, glo, ghi, side, width1, width2, clo, chi, t)
    it = 0
    while act.size and it < MAX_ITER:
        it += 1
        tm, pts = bracket_points(act, br, tol_t, it, a, d)
        f = _field(skel, pts)[0]
        evals += act.size
        act = bracket_update(act, tm, f, br, reach_t, length, float(tol), FIELD_SLACK)
    if act.size:   # pragma: no cover - the bisection safeguard makes this unreachable
        t[act] = 0.5 * (lo[act] + hi[act])
    return a + t[:, None] * d, t, bracketed, evals



def plane_distance(skel: Skeleton, xy: np.ndarray, z: float):
    """``|F − 1| / ‖∇_xy F‖`` of points of the plane ``z`` (inf where the
    gradient vanishes), with F and the gradient."""
    p = np.column_stack([xy, np.full(xy.shape[0], float(z))])
    f, g = _field(skel, p, gradient=True)
    gxy = g[:, :2]
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(gn > 0, np.abs(f - 1.0) / gn, np.inf)
    return dist, f, gxy


def project_to_contour(skel: Skeleton, xy: np.ndarray, z: float, tol: float, reach=None):
    """:func:`slicer.contours.roots.project_to_contour` in batches: the Newton
    brackets of all points, then the whole segments of the rest."""
    n = xy.shape[0]
    dist, f, gxy = plane_distance(skel, xy, z)
    gn = np.hypot(gxy[:, 0], gxy[:, 1])
    usable = np.isfinite(dist)
    r = np.where(usable, 3.0 * np.where(usable, dist, 0.0) + tol, 0.0)
    if reach is not None:
        r = np.minimum(r, reach)
    nrm = gxy / np.where(gn > 0, gn, 1.0)[:, None]          # toward growing F: inward
    zz = np.full(n, float(z))
    A = np.column_stack([xy + r[:, None] * nrm, zz])
    B = np.column_stack([xy - r[:, None] * nrm, zz])
    roots = xy.copy()
    ok = np.zeros(n, bool)
    evals = n
    idx = np.flatnonzero(usable & (r > 0))
    # the Newton point, bracketed tol/2 either side (within the search segment)
    near = idx[dist[idx] + 0.5 * tol <= r[idx]]
    if near.size:
        step = ((1.0 - f[near]) / gn[near])[:, None] * nrm[near]
        half = 0.4999 * tol * nrm[near]          # a bracket just under tol: its midpoint, no iteration
        pts, _, br, ne = solve_crossings(skel, np.column_stack([xy[near] + step + half, zz[near]]),
                                         np.column_stack([xy[near] + step - half, zz[near]]), tol)
        evals += ne
        roots[near[br]] = pts[br, :2]
        ok[near[br]] = True
        idx = np.setdiff1d(idx, near[br], assume_unique=True)
    if idx.size:
        pts, _, br, ne = solve_crossings(skel, A[idx], B[idx], tol)
        evals += ne
        roots[idx[br]] = pts[br, :2]
        ok[idx[br]] = True
    return roots, ok, dist, evals


def refine_rings(skel: Skeleton, rings: list[np.ndarray], z: float, tol: float,
                 stats: dict | None = None, max_rounds: int = 8,
                 certified: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """:func:`slicer.contours.simplify.refine_rings` in whole-array rounds."""
    if not rings:
        return rings
    sizes = np.array([r.shape[0] for r in rings])
    xy = np.concatenate(rings)
    ring_of = np.repeat(np.arange(len(rings)), sizes)
    done = np.concatenate(certified) if certified is not None else np.zeros(xy.shape[0], bool)
    added = 0
    evals = 0
    checks = 0
    for _ in range(max_rounds):
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        nxt = np.arange(xy.shape[0]) + 1
        nxt[starts + sizes - 1] = starts
        p, q = xy, xy[nxt]
        chord = np.hypot(*(q - p).T)
        todo = np.flatnonzero(~done & (chord > 2 * tol))
        if todo.size == 0:
            break
        # quarter points too: on a chord across varying curvature the largest
        # deviation need not be at the midpoint
        fr = np.array([0.25, 0.5, 0.75])[None, :, None]
        pt, qt = p[todo], q[todo]
        m3 = (pt[:, None, :] + fr * (qt - pt)[:, None, :]).reshape(-1, 2)
        dist = np.full(xy.shape[0], 0.0)
        dist[todo] = plane_distance(skel, m3, z)[0].reshape(-1, 3).max(axis=1)
        evals += m3.shape[0]
        checks += m3.shape[0]
        bad = todo[~(dist[todo] <= CHORD_FRACTION * tol)]
        done[todo] = True                    # checked: fine, or split below
        done[bad] = False
        if bad.size == 0:
            break
        # a chord's sagitta shrinks as its length squared: split it into
        # about sqrt(dist / tol) pieces at once (fewer rounds, fewer launches)
        with np.errstate(invalid="ignore"):
            goal = CHORD_FRACTION * tol
            nsub = np.clip(np.ceil(1.2 * np.sqrt(np.where(np.isfinite(dist[bad]), dist[bad], 4 * goal) / goal)),
                           2, 64).astype(np.int64)
        owner = np.repeat(bad, nsub - 1)
        j = np.arange(owner.size) - np.repeat(np.cumsum(nsub - 1) - (nsub - 1), nsub - 1) + 1
        frac = j / np.repeat(nsub, nsub - 1)
        cand = p[owner] + frac[:, None] * (q[owner] - p[owner])
        roots, ok, _, ne = project_to_contour(skel, cand, z, tol, reach=0.25 * chord[owner])
        evals += ne
        if not ok.any():
            break
        ins = owner[ok]
        # insert the new vertices after vertex ``ins``, in order along the chord
        pos = np.concatenate([np.arange(xy.shape[0]), ins])
        sub = np.concatenate([np.zeros(xy.shape[0], np.int64), j[ok]])
        order = np.lexsort((sub, pos))
        xy = np.concatenate([xy, roots[ok]])[order]
        ring_of = np.concatenate([ring_of, ring_of[ins]])[order]
        done = np.concatenate([done, np.zeros(ins.size, bool)])[order]
        sizes = np.bincount(ring_of, minlength=len(rings))
        added += ins.size
    if stats is not None:
        stats["refined"] = stats.get("refined", 0) + added
        stats["evaluations"] = stats.get("evaluations", 0) + evals
        stats["check_evaluations"] = stats.get("check_evaluations", 0) + checks
        stats["projection_evaluations"] = stats.get("projection_evaluations", 0) + evals - checks
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    return [xy[bounds[q]:bounds[q + 1]] for q in range(len(rings))]
