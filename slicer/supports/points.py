"""Support points: where a model needs holding, from its exact slices and field.

Three sources, all on the grid the model is checked on:

* **islands** (:func:`unheld_regions`): the regions of a layer held by
  nothing below, exactly as ``skelslice check`` finds them
  (:class:`slicer.printability.IslandFinder`); with the model lifted off the
  plate, its lowest layer's regions too;
* **local minima along z** (:func:`skeleton_minima`): nodes none of whose
  struts goes down (tips, the bottom of a V), found on the skeleton, so a
  minimum that a coarser or shifted grid would miss still gets a support;
* **spans**: each unheld region is covered by points no farther apart than the
  bridge length (:func:`region_points`, farthest-point sampling of its
  pixels), so no part of it is left unsupported over a longer span;
* **overhangs** (:func:`overhang_pixels`): surfaces flatter than a critical
  angle whose pixels lie farther than the bridge length from what holds them.

A point's contact height is the model's underside there, found on the exact
field by bisection (:func:`underside`).
"""
from __future__ import annotations

import numpy as np

from slicer.tracer.grid import SliceGrid
from slicer.printability.islands import IslandFinder

#: bisection steps for heights on the field (2^-40 of a layer)
BISECT = 40


class RegionFinder(IslandFinder):
    """:class:`~slicer.printability.IslandFinder` that keeps each island's pixels.

    Parameters
    ----------
    grid : SliceGrid
    plate_held : bool
        The lowest solid layer rests on the plate (``check``'s rule); False
        reports its regions too (a model lifted off the plate).

    Attributes
    ----------
    regions : list of (k, ii, jj)
        Layer and pixel columns and rows ((p,) int64 each) of every unheld region.
    """

    def __init__(self, grid: SliceGrid, plate_held: bool = True):
        super().__init__(grid)
        self.regions: list[tuple[int, np.ndarray, np.ndarray]] = []
        if not plate_held:
            self._below = np.zeros((grid.height, grid.width), bool)

    def _record(self, k: int, st: np.ndarray, held: np.ndarray) -> None:
        super()._record(k, st, held)
        for r in np.nonzero(~held)[0]:
            jj, ii = np.nonzero(self._labels == r)
            self.regions.append((int(k), ii.astype(np.int64), jj.astype(np.int64)))


def unheld_regions(result, plate_held: bool = True) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The unheld regions of a traced result's layers (see :class:`RegionFinder`).

    Parameters
    ----------
    result : SliceResult
    plate_held : bool

    Returns
    -------
    list of (k, ii, jj)
    """
    finder = RegionFinder(result.grid, plate_held)
    for k, img in enumerate(result.iter_layers()):
        finder.add(k, img > 0)
    return finder.regions


def region_points(grid: SliceGrid, ii: np.ndarray, jj: np.ndarray, spacing: float) -> np.ndarray:
    """Pixels of one region that support it: the one nearest its centroid, then the
    farthest from those chosen until every pixel is within ``spacing`` of one.

    Parameters
    ----------
    grid : SliceGrid
    ii, jj : (p,) int64
        Columns and rows of the region's pixels.
    spacing : float, mm

    Returns
    -------
    (q, 2) int64
        Columns and rows of the chosen pixels, in the order chosen.
    """
    px, py = grid.pixel_size
    xy = np.stack([ii * px, jj * py], axis=1).astype(np.float64)
    c = xy.mean(axis=0)
    first = int(np.argmin(((xy - c) ** 2).sum(axis=1)))
    chosen = [first]
    d = np.sqrt(((xy - xy[first]) ** 2).sum(axis=1))
    while d.max() > spacing:
        q = int(np.argmax(d))
        chosen.append(q)
        d = np.minimum(d, np.sqrt(((xy - xy[q]) ** 2).sum(axis=1)))
    return np.stack([ii[chosen], jj[chosen]], axis=1)


def skeleton_minima(skel) -> np.ndarray:
    """Nodes that are local minima of the skeleton along z: used by a segment, and no
    segment goes down from them (every other end is at least as high).

    Returns
    -------
    (q,) int64
        Node indices, increasing.
    """
    seg = skel.segments
    z = skel.nodes[:, 2]
    used = np.zeros(skel.n_nodes, bool)
    used[seg.ravel()] = True
    down = np.zeros(skel.n_nodes, bool)
    down[seg[:, 0][z[seg[:, 1]] < z[seg[:, 0]]]] = True
    down[seg[:, 1][z[seg[:, 0]] < z[seg[:, 1]]]] = True
    return np.nonzero(used & ~down)[0].astype(np.int64)


def bisect_z(field, xy: np.ndarray, z_in: np.ndarray, z_out: np.ndarray) -> np.ndarray:
    """Heights where the field crosses 1 between an inside and an outside height per column.

    Parameters
    ----------
    field : callable
        ``field((k, 3) float64 mm) -> (k,) float64``.
    xy : (q, 2) float64, mm
    z_in, z_out : (q,) float64, mm
        Heights with ``F >= 1`` and ``F < 1``.

    Returns
    -------
    (q,) float64, mm
        The inside end of the final bracket (``F >= 1`` there).
    """
    zi, zo = z_in.astype(np.float64).copy(), z_out.astype(np.float64).copy()
    for _ in range(BISECT):
        zm = 0.5 * (zi + zo)
        inside = field(np.column_stack([xy, zm])) >= 1.0
        zi = np.where(inside, zm, zi)
        zo = np.where(inside, zo, zm)
    return zi


def march(field, xy: np.ndarray, z0: np.ndarray, step: float, stop: np.ndarray, want_inside: bool,
          chunk: int = 64):
    """Walk each column from ``z0`` by ``step`` (negative: down) until the field is inside
    (``want_inside``) or outside, or ``stop`` is passed; ``chunk`` steps of every live
    column are evaluated in one call.

    Returns
    -------
    z : (q,) float64, mm
        The first height found, or NaN where ``stop`` came first.
    """
    q = len(z0)
    found = np.full(q, np.nan)
    z = z0.astype(np.float64).copy()
    live = np.arange(q)
    steps = np.arange(chunk, dtype=np.float64) * step
    while live.size:
        zz = z[live, None] + steps[None, :]                       # (live, chunk)
        past = (zz < stop[live, None]) if step < 0 else (zz > stop[live, None])
        pts = np.column_stack([np.repeat(xy[live], chunk, axis=0), zz.ravel()])
        inside = (field(pts) >= 1.0).reshape(len(live), chunk)
        hit = (inside if want_inside else ~inside) & ~past
        # a hit counts only before the column's first step past ``stop``
        first_past = np.where(past.any(axis=1), past.argmax(axis=1), chunk)
        first_hit = np.where(hit.any(axis=1), hit.argmax(axis=1), chunk)
        got = first_hit < first_past
        found[live[got]] = zz[got, first_hit[got]]
        done = got | (first_past < chunk)
        z[live] += chunk * step
        live = live[~done]
    return found


def underside(field, xy: np.ndarray, z_inside: np.ndarray, step: float) -> np.ndarray:
    """The model's underside below inside points: walk down until outside, then bisect.

    Parameters
    ----------
    field : callable
    xy : (q, 2) float64, mm
    z_inside : (q,) float64, mm
        Heights inside the solid (``F >= 1``) in each column.
    step : float, mm
        Walking step (> 0), at most the thinnest feature to step over.

    Returns
    -------
    (q,) float64, mm
        The lowest inside height of the solid piece each point is in, to 2^-40 step.
    """
    out = march(field, xy, z_inside - step, -step, np.full(len(z_inside), -np.inf), False)
    z_in = out + step
    return bisect_z(field, xy, z_in, out)


def _grow(mask: np.ndarray, r: int) -> np.ndarray:
    """``mask`` dilated by a (2r + 1)-pixel square (r = 0: itself)."""
    out = mask.copy()
    h, w = mask.shape
    for dj in range(-r, r + 1):
        for di in range(-r, r + 1):
            if di or dj:
                out[max(dj, 0):h + min(dj, 0), max(di, 0):w + min(di, 0)] |= \
                    mask[max(-dj, 0):h + min(-dj, 0), max(-di, 0):w + min(-di, 0)]
    return out


def _reached(anchors: np.ndarray, solid: np.ndarray, steps: int) -> np.ndarray:
    """Pixels of ``solid`` within ``steps`` 8-connected steps of ``anchors`` through ``solid``."""
    reached = anchors & solid
    for _ in range(steps):
        more = _grow(reached, 1) & solid
        if np.array_equal(more, reached):
            break
        reached = more
    return reached


def _disc(mask: np.ndarray, i: int, j: int, r: int) -> None:
    """Set a (2r + 1)-pixel square around column ``i``, row ``j`` (clipped to the mask)."""
    h, w = mask.shape
    mask[max(j - r, 0):min(j + r + 1, h), max(i - r, 0):min(i + r + 1, w)] = True


def overhang_pixels(result, grid: SliceGrid, held_xyz: np.ndarray, angle: float, bridge: float,
                    tip: float) -> list[tuple[int, int, int]]:
    """Pixels of overhangs flatter than ``angle`` that lie farther than ``bridge`` from
    anything holding them, and how they are held once supported.

    A pixel of layer k is an *overhang* when no pixel of layer k - 1 within
    ``h / tan(angle)`` (a square of that half-width) is solid: the surface there
    is flatter than ``angle`` from the horizontal. Its layer's other solid
    pixels hold it, as do support contacts at or below the layer (a square of
    half-width ``tip`` around each); an overhang pixel more than ``bridge`` away
    from them, counted in 8-connected steps through the layer's solid, gets
    support points: farthest-point sampling of those pixels with spacing
    ``bridge`` (:func:`region_points`), each then holding the rest.

    Parameters
    ----------
    result : SliceResult
        The model's slices (on ``grid``'s pixels).
    grid : SliceGrid
        Where the pixels are (the lifted model's frame).
    held_xyz : (q, 3) float64, mm
        Support contacts already chosen.
    angle : float, degrees
        Critical angle from the horizontal, in (0, 90).
    bridge, tip : float, mm

    Returns
    -------
    list of (k, i, j)
        Layer, column and row of each new support pixel, bottom layer first.
    """
    px = grid.pixel_size[0]
    h = grid.layer_height
    r_below = int(np.floor(h / np.tan(np.radians(angle)) / px + 1e-9))
    steps = int(np.ceil(bridge / px))
    rt = int(np.floor(tip / px))
    held = np.asarray(held_xyz, dtype=np.float64).reshape(-1, 3)
    hi = np.rint((held[:, 0] - grid.origin[0]) / px).astype(np.int64)
    hj = np.rint((grid.origin[1] - held[:, 1]) / grid.pixel_size[1]).astype(np.int64)
    out: list[tuple[int, int, int]] = []
    below = None
    for k, img in enumerate(result.iter_layers()):
        solid = img > 0
        if below is None:
            below = solid if solid.any() else None
            continue
        new = solid & ~_grow(below, r_below)
        below = solid
        if not new.any():
            continue
        z = grid.origin[2] + k * h
        jj, ii = np.nonzero(new)
        j0, j1 = max(jj.min() - steps - 1, 0), min(jj.max() + steps + 2, solid.shape[0])
        i0, i1 = max(ii.min() - steps - 1, 0), min(ii.max() + steps + 2, solid.shape[1])
        s, n = solid[j0:j1, i0:i1], new[j0:j1, i0:i1]
        anchors = s & ~n
        for q in np.nonzero(held[:, 2] <= z + 1e-9)[0]:
            _disc(anchors, int(hi[q] - i0), int(hj[q] - j0), rt)
        far = n & ~_reached(anchors, s, steps)
        if not far.any():
            continue
        fj, fi = np.nonzero(far)
        for i, j in region_points(grid, fi + i0, fj + j0, bridge):
            out.append((k, int(i), int(j)))
            held = np.vstack([held, [[grid.origin[0] + i * px, grid.origin[1] - j * grid.pixel_size[1], z]]])
            hi, hj = np.append(hi, i), np.append(hj, j)
    return out


__all__ = ["RegionFinder", "unheld_regions", "region_points", "skeleton_minima", "bisect_z", "march", "underside",
           "overhang_pixels"]
