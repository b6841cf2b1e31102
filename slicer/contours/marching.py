"""Marching squares on an exactly classified raster (pixel centres), the
contours of the raster: vertices root-solved on the pixel edges."""
from __future__ import annotations

import numpy as np

from slicer._kernels.contours.chain import chain_rings
from slicer.errors import GridError
from slicer.model.skeleton import Skeleton
from slicer.tracer.slicing import SliceResult
from slicer.contours.roots import _field, solve_crossings
from slicer.contours.simplify import _keep_simple, refine_rings

# Cell corners TL, TR, BR, BL (bits 1, 2, 4, 8) and edges T, R, B, L (0..3),
# seen from above with +y up. Walking the corners counter-clockwise,
# TL -> BL -> BR -> TR -> TL, crosses the edges L, B, R, T in turn.
_CCW_CORNERS = (0, 3, 2, 1)         # TL, BL, BR, TR
_CCW_EDGES = (3, 2, 1, 0)           # edge from _CCW_CORNERS[q] to _CCW_CORNERS[q + 1]


def _case_table():
    """Oriented segments (from edge, to edge) per marching-squares case.

    A segment runs from an edge where the counter-clockwise walk leaves the
    inside to an edge where it enters it, so the inside is on its left: outer
    boundaries come out counter-clockwise, holes clockwise. In the two saddle
    cases the pairing depends on the cell centre: ``joined`` (centre inside)
    pairs each exit with the next entry, ``separate`` with the previous one.

    Returns
    -------
    (16, 2, 2, 2) int64
        ``table[case, saddle_joined, s] = (from, to)``; unused slots are -1.
    """
    table = -np.ones((16, 2, 2, 2), np.int64)
    for case in range(16):
        inside = [(case >> c) & 1 for c in _CCW_CORNERS]
        exits, entries = [], []
        for q in range(4):
            a, b = inside[q], inside[(q + 1) % 4]
            if a and not b:
                exits.append(q)
            elif b and not a:
                entries.append(q)
        for joined in (0, 1):
            for s, q in enumerate(exits):
                later = [e for e in entries if e > q] + [e for e in entries if e < q]
                partner = later[0] if (joined or len(entries) == 1) else later[-1]
                table[case, joined, s] = (_CCW_EDGES[q], _CCW_EDGES[partner])
    return table


_TABLE = _case_table()


def layer_mask(result: SliceResult, k: int) -> np.ndarray:
    """Layer ``k`` of a result as a (height, width) bool image (True inside)."""
    g = result.grid
    k = int(k)
    if not 0 <= k < g.layers:
        raise GridError(f"layer {k} is out of range (the stack has {g.layers} layers)")
    sel = (result.k0 <= k) & (k < result.k1)
    img = np.zeros(g.width * g.height, bool)
    img[result.pix[sel]] = True
    return img.reshape(g.height, g.width)


def mask_rings(skel: Skeleton, mask: np.ndarray, origin, pixel_size, z: float, tol: float = 1e-3,
               refine: bool = True, stats: dict | None = None, values: np.ndarray | None = None
               ) -> list[np.ndarray]:
    """Closed rings of the inside region of one exactly classified raster.

    Parameters
    ----------
    skel : Skeleton
    mask : (H, W) bool
        True where the pixel centre is inside (``F >= 1``).
    origin : (2,) float64, mm
        Centre of pixel (row 0, column 0); rows run toward -y.
    pixel_size : (2,) float64, mm
    z : float, mm
        Height of the layer.
    tol : float, mm
        Root tolerance along pixel edges, and chord tolerance if ``refine``.
    refine : bool
        Subdivide chords until their midpoints and quarter points are within
        ``tol / 2`` of the surface.
    stats : dict, optional
        Updated with ``evaluations``, ``vertices``, ``unbracketed``, ``refined``,
        ``unrefined_rings`` (rings whose refinement was undone to keep them
        simple and disjoint).
    values : (H, W) float64, optional
        The field at the pixel centres. Given, vertices are placed by linear
        interpolation of ``F - 1`` along the edges and saddles by the mean of
        the four corners, with no field evaluation: the classic dense-grid
        marching squares (a baseline, not the default).

    Returns
    -------
    list of (n_q, 2) float64
        Ring vertices, not repeated at the end; outer rings counter-clockwise,
        holes clockwise.
    """

    mask = np.asarray(mask, bool)
    H, W = mask.shape
    x0, y0 = float(origin[0]), float(origin[1])
    px, py = float(pixel_size[0]), float(pixel_size[1])
    st = {"evaluations": 0, "vertices": 0, "unbracketed": 0, "refined": 0, "unrefined_rings": 0}
    if not mask.any():
        if stats is not None:
            for key, v in st.items():
                stats[key] = stats.get(key, 0) + v
        return []
    P = np.zeros((H + 2, W + 2), bool)
    P[1:-1, 1:-1] = mask
    # boundary edges: horizontal hx[j, i] joins (j, i)-(j, i+1); vertical vy[j, i] joins (j, i)-(j+1, i)
    hx = P[:, :-1] != P[:, 1:]                 # (H+2, W+1)
    vy = P[:-1, :] != P[1:, :]                 # (H+1, W+2)
    nh = hx.size
    hj, hi_ = np.nonzero(hx)
    vj, vi = np.nonzero(vy)
    # inside / outside ends of each boundary edge, padded indices
    h_in_left = P[hj, hi_]
    v_in_top = P[vj, vi]
    ej_in = np.concatenate([hj, np.where(v_in_top, vj, vj + 1)])
    ei_in = np.concatenate([np.where(h_in_left, hi_, hi_ + 1), vi])
    ej_out = np.concatenate([hj, np.where(v_in_top, vj + 1, vj)])
    ei_out = np.concatenate([np.where(h_in_left, hi_ + 1, hi_), vi])

    def world(jp, ip):
        return np.stack([x0 + (ip - 1) * px, y0 - (jp - 1) * py, np.full(jp.shape, float(z))], axis=1)

    a = world(ej_in, ei_in)
    b = world(ej_out, ei_out)
    # an edge to a pixel beyond the grid ends at the grid's box, half a pixel out
    border = (ej_out == 0) | (ei_out == 0) | (ej_out == H + 1) | (ei_out == W + 1)
    verts = np.empty((a.shape[0], 3))
    verts[border] = 0.5 * (a[border] + b[border])
    inner = ~border
    if values is not None and inner.any():
        V = np.zeros((H + 2, W + 2))
        V[1:-1, 1:-1] = values
        fa = V[ej_in, ei_in][inner]
        fb = V[ej_out, ei_out][inner]
        tt = np.clip((fa - 1.0) / (fa - fb), 1e-6, 1.0 - 1e-6)
        verts[inner] = a[inner] + tt[:, None] * (b[inner] - a[inner])
    elif inner.any():
        pts, tt, ok, ne = solve_crossings(skel, a[inner], b[inner], tol)
        # keep vertices off the pixel centres so that rings stay simple
        eps = 1e-6
        tt = np.clip(tt, eps, 1.0 - eps)
        verts[inner] = a[inner] + tt[:, None] * (b[inner] - a[inner])
        st["evaluations"] += ne
        st["unbracketed"] += int((~ok).sum())
    # compact vertex index of every boundary edge id
    edge_id = np.concatenate([hj * (W + 1) + hi_, nh + vj * (W + 2) + vi])
    lookup = np.full(nh + vy.size, -1, np.int64)
    lookup[edge_id] = np.arange(edge_id.size)
    # marching-squares cells (H+1, W+1) with corners TL, TR, BR, BL
    case = (P[:-1, :-1].astype(np.int64) | (P[:-1, 1:] << 1) | (P[1:, 1:] << 2) | (P[1:, :-1] << 3))
    cj, ci = np.nonzero((case != 0) & (case != 15))
    cc = case[cj, ci]
    joined = np.zeros(cc.shape, np.int64)
    sad = np.flatnonzero((cc == 5) | (cc == 10))
    if sad.size and values is not None:
        V = np.zeros((H + 2, W + 2))
        V[1:-1, 1:-1] = values
        mean = 0.25 * (V[cj[sad], ci[sad]] + V[cj[sad], ci[sad] + 1] + V[cj[sad] + 1, ci[sad]]
                       + V[cj[sad] + 1, ci[sad] + 1])
        joined[sad] = (mean >= 1.0).astype(np.int64)
    elif sad.size:
        cen = np.stack([x0 + (ci[sad] - 0.5) * px, y0 - (cj[sad] - 0.5) * py,
                        np.full(sad.size, float(z))], axis=1)
        joined[sad] = (_field(skel, cen)[0] >= 1.0).astype(np.int64)
        st["evaluations"] += sad.size
    # edge ids of the four cell edges T, R, B, L
    cell_edges = np.stack([cj * (W + 1) + ci, nh + cj * (W + 2) + ci + 1,
                           (cj + 1) * (W + 1) + ci, nh + cj * (W + 2) + ci], axis=1)
    seg = _TABLE[cc, joined]                   # (c, 2, 2)
    use = seg[:, :, 0] >= 0
    rows = np.nonzero(use)
    f_edge = cell_edges[rows[0], seg[rows[0], rows[1], 0]]
    t_edge = cell_edges[rows[0], seg[rows[0], rows[1], 1]]
    nxt = np.full(edge_id.size, -1, np.int64)
    nxt[lookup[f_edge]] = lookup[t_edge]
    order, starts, status = chain_rings(nxt)
    if status != 0:   # pragma: no cover - a marching-squares invariant
        raise RuntimeError("contour chaining failed: segments do not form closed rings")
    xy = verts[:, :2]
    rings = [xy[order[starts[q]:starts[q + 1]]] for q in range(starts.size - 1)]
    st["vertices"] += int(edge_id.size)
    if refine:
        rings = _keep_simple(refine_rings(skel, rings, float(z), tol, st), rings, st)
    if stats is not None:
        for key, v in st.items():
            stats[key] = stats.get(key, 0) + v
    return rings


__all__ = ["layer_mask", "mask_rings"]
