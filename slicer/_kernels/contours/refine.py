"""Chord refinement of a layer's contour rings in one compiled call
(:func:`slicer.contours.simplify.refine_rings` validates and documents it).

Rings travel flat: ``xy`` (n, 2) float64, mm, the vertices of all rings one
ring after another, ``ring`` (n,) int64 the ring of each (non-decreasing),
``done`` (n,) bool the chords ``i -> i + 1`` (cyclic in each ring) known to
be within the tolerance. The field travels as
:mod:`slicer._kernels.contours.crossings` takes it. Rounds run as a batch of chords
would: every chord checked, then every stray one split, then the new
vertices inserted, so the rings and the counts are those of a vectorised
pass to the bit.
"""
from __future__ import annotations

import math

import numpy as np

from slicer._jit import inline_kernel, kernel
from slicer._kernels.contours.brackets import np_maximum
from slicer._kernels.contours.crossings import distance_at, project_one
from slicer._kernels.field.segment import SCRATCH


@kernel
def ring_next(ring):
    """Index of each vertex's successor in its ring (the first after the
    last), (n,) int64, for rings stored one after another."""
    n = ring.shape[0]
    nxt = np.empty(n, np.int64)
    start = 0
    for i in range(n):
        if i > 0 and ring[i] != ring[i - 1]:
            start = i
        nxt[i] = i + 1 if i + 1 < n and ring[i + 1] == ring[i] else start
    return nxt


@inline_kernel
def chord_distance(fld, p, q, z, scratch):
    """The largest first-order distance to the contour of the quarter
    points and the midpoint of the chord ``p -> q`` (2-tuples, mm; NaN if
    any is NaN): on a chord across varying curvature the largest deviation
    need not be at the midpoint."""
    worst = 0.0
    px, py = p
    qx, qy = q
    for k in range(3):
        fr = 0.25 * (k + 1)
        d = distance_at(fld, px + fr * (qx - px), py + fr * (qy - py), z, scratch)[0]
        worst = d if k == 0 else np_maximum(worst, d)
    return worst


@inline_kernel
def split_count(dist, goal):
    """Pieces a chord whose distance is ``dist`` is split into: a chord's
    sagitta shrinks as its length squared, so about ``sqrt(dist / goal)``
    (``4 goal`` for a distance that is not finite), from 2 to 64."""
    v = dist if math.isfinite(dist) else 4.0 * goal
    return int(min(max(np.ceil(1.2 * math.sqrt(v / goal)), 2.0), 64.0))


@kernel
def check_chords(fld, xy, nxt, done, z, tol, goal, scratch):
    """One round's checks: the chords not ``done`` and longer than ``2 tol``
    get :func:`chord_distance`; those within ``goal`` become ``done``.

    Returns
    -------
    chord : (n,) float64
        Every chord's length, mm.
    pieces : (n,) int64
        :func:`split_count` of each stray chord, 0 for the others.
    checked, stray : int
        Chords checked (three evaluations each), and those of them not
        within ``goal``.
    """
    n = xy.shape[0]
    chord = np.empty(n)
    pieces = np.zeros(n, np.int64)
    checked = 0
    stray = 0
    for i in range(n):
        j = nxt[i]
        chord[i] = math.hypot(xy[j, 0] - xy[i, 0], xy[j, 1] - xy[i, 1])
        if done[i] or not chord[i] > 2.0 * tol:
            continue
        checked += 1
        d = chord_distance(fld, (xy[i, 0], xy[i, 1]), (xy[j, 0], xy[j, 1]), z, scratch)
        done[i] = d <= goal
        if not done[i]:
            pieces[i] = split_count(d, goal)
            stray += 1
    return chord, pieces, checked, stray


@kernel
def split_chords(fld, xy, nxt, chord, pieces, z, tol, slack, scratch):
    """New vertices of the stray chords (``pieces > 0``): the chord's
    points at ``j / pieces`` (j = 1 .. pieces − 1) put on the contour
    (:func:`slicer._kernels.contours.crossings.project_one`, at most a quarter of the
    chord away), in chord order and then j order.

    Returns
    -------
    new : (k, 2) float64
        The points that found the contour.
    owner : (k,) int64
        The vertex each follows.
    evaluations : int
    """
    total = 0
    for i in range(xy.shape[0]):
        total += max(pieces[i] - 1, 0)
    new = np.empty((total, 2))
    owner = np.empty(total, np.int64)
    k = 0
    ev = 0
    for i in range(xy.shape[0]):
        j2 = nxt[i]
        for j in range(1, pieces[i]):
            frac = j / pieces[i]
            x = xy[i, 0] + frac * (xy[j2, 0] - xy[i, 0])
            y = xy[i, 1] + frac * (xy[j2, 1] - xy[i, 1])
            rx, ry, ok, _, e = project_one(fld, x, y, z, tol, 0.25 * chord[i], slack, scratch)
            ev += e
            if ok:
                new[k, 0] = rx
                new[k, 1] = ry
                owner[k] = i
                k += 1
    return new[:k], owner[:k], ev


@kernel
def insert_after(xy, ring, done, new, owner):
    """The rings with the vertices ``new`` inserted, each after vertex
    ``owner`` (non-decreasing; in their order after one owner), not ``done``.

    Returns
    -------
    xy, ring, done : the arrays with the new vertices
    """
    n = xy.shape[0]
    k = new.shape[0]
    oxy = np.empty((n + k, 2))
    oring = np.empty(n + k, np.int64)
    odone = np.empty(n + k, np.bool_)
    q = 0
    o = 0
    for i in range(n):
        oxy[o, 0], oxy[o, 1], oring[o], odone[o] = xy[i, 0], xy[i, 1], ring[i], done[i]
        o += 1
        while q < k and owner[q] == i:
            oxy[o, 0], oxy[o, 1], oring[o], odone[o] = new[q, 0], new[q, 1], ring[i], False
            o += 1
            q += 1
    return oxy, oring, odone


@kernel
def refine_chords(fld, xy, ring, done, z, tols, rounds, slack):
    """Up to ``rounds`` rounds of :func:`check_chords`, :func:`split_chords`
    and :func:`insert_after`; ``tols = (tol, goal)``: the tolerance and the
    distance a chord must keep to. Stops early when no chord is checked,
    none strays, or no new point found the contour.

    Returns
    -------
    xy : (n', 2) float64
    ring : (n',) int64
    counts : (added, evaluations, checks)
    """
    tol, goal = tols
    scratch = np.empty(SCRATCH)
    added = 0
    evals = 0
    checks = 0
    for _ in range(rounds):
        nxt = ring_next(ring)
        chord, pieces, checked, stray = check_chords(fld, xy, nxt, done, z, tol, goal, scratch)
        if checked == 0:
            break
        evals += 3 * checked
        checks += 3 * checked
        if stray == 0:
            break
        new, owner, ev = split_chords(fld, xy, nxt, chord, pieces, z, tol, slack, scratch)
        evals += ev
        if new.shape[0] == 0:
            break
        xy, ring, done = insert_after(xy, ring, done, new, owner)
        added += new.shape[0]
    return xy, ring, (added, evals, checks)
