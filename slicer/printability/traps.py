"""Resin traps: cavities of the solid that do not drain.

The empty voxels of the stack, from the lowest layer with a solid pixel up,
form components (6-connected in 3-D: 4-connected within a layer, and
joined between consecutive layers at the same pixel). What "drains" means
for a resin print, which hangs from the build plate and is lifted out of
the vat:

* a component that reaches the side of the window (beyond it everything is
  empty) or the top of the stack (above the last layer: the vat) is open;
* the build plate lies under the lowest solid layer, so a component that
  reaches the bottom is closed by the plate: a *suction cup* (kind
  ``"plate"``: it holds resin and pulls on every peel);
* a component that reaches neither is a closed cavity (kind ``"closed"``):
  uncured resin stays inside the print.

Both kinds are reported with their volume (voxels x voxel volume), centroid
and layer range. Layers stream bottom to top; only the previous layer's
labels and the bookkeeping of the components still open to the current
layer are kept (O(layer) + O(live components)); a component is final once
a layer has none of its voxels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer._kernels.raster.labels import label_layer, link_layers, region_stats
from slicer.tracer.grid import SliceGrid
from slicer.printability.stream import rounded

#: bookkeeping columns of a component: voxels, sum i, sum j, sum k, i0, j0, k0, i1, j1, k1, open, plate
_N, _SI, _SJ, _SK, _I0, _J0, _K0, _I1, _J1, _K1, _OPEN, _PLATE = range(12)
_SUMS = [_N, _SI, _SJ, _SK]
_MINS = [_I0, _J0, _K0]
_MAXS = [_I1, _J1, _K1, _OPEN, _PLATE]


@dataclass(frozen=True)
class Trap:
    """A cavity of the solid that holds resin.

    Attributes
    ----------
    kind : {"closed", "plate"}
        Closed on every side, or open only to the build plate (a suction cup).
    volume : float, mm³
        Empty voxels x voxel volume.
    voxels : int
    x, y, z : float, mm
        Centroid of its voxel centres.
    layers : (2,) int
        First and last layer it occupies.
    bbox : (6,) int
        ``[i0, j0, k0, i1, j1, k1]`` (inclusive) in the stack's window.
    """

    kind: str
    volume: float
    voxels: int
    x: float
    y: float
    z: float
    layers: tuple[int, int]
    bbox: tuple[int, int, int, int, int, int]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "volume": rounded(self.volume), "voxels": self.voxels, "x": rounded(self.x),
                "y": rounded(self.y), "z": rounded(self.z), "layers": list(self.layers), "bbox": list(self.bbox)}


class TrapFinder:
    """Finds resin traps in a stream of solid masks (:meth:`add` per layer, then :meth:`finish`).

    Parameters
    ----------
    grid : SliceGrid
    """

    def __init__(self, grid: SliceGrid):
        self.grid = grid
        self.traps: list[Trap] = []
        self._started = False
        self._below = np.empty((grid.height, grid.width), np.int32)
        self._above = np.empty((grid.height, grid.width), np.int32)
        self._live = np.zeros((0, 12), np.float64)      # bookkeeping of the components in the last layer

    def add(self, k: int, solid: np.ndarray) -> None:
        """Layer ``k``'s solid mask, (height, width) bool."""
        if not self._started:
            if not solid.any():
                return
            self._started = True
            plate = True
        else:
            plate = False
        empty = np.ascontiguousarray(~solid).view(np.uint8)
        n = label_layer(empty, False, self._above)
        stats = self._layer_stats(k, n, plate)
        m = self._live.shape[0]
        group = link_layers(self._below, self._above, m, n) if m else np.arange(n, dtype=np.int64)
        nodes = np.concatenate([self._live, stats]) if m else stats
        keys, inv = np.unique(group, return_inverse=True)
        merged = _combine(nodes, inv, len(keys))
        alive = np.zeros(len(keys), bool)
        alive[inv[m:]] = True
        for row in merged[~alive]:
            self._emit(row)
        # relabel the current layer with the live groups, in order
        new_id = np.full(len(keys), -1, np.int64)
        new_id[alive] = np.arange(int(alive.sum()))
        lab_map = new_id[inv[m:]].astype(np.int32)
        above = self._above
        inside = above >= 0
        above[inside] = lab_map[above[inside]]
        self._live = merged[alive]
        self._below, self._above = above, self._below

    def finish(self) -> list[Trap]:
        """Close the stream: the components in the last layer are open to the vat."""
        self._live = np.zeros((0, 12), np.float64)
        self.traps.sort(key=lambda t: (t.layers[0], t.bbox[1], t.bbox[0]))
        return self.traps

    def _layer_stats(self, k: int, n: int, plate: bool) -> np.ndarray:
        """Bookkeeping rows of the ``n`` empty regions of the current layer."""
        lab = self._above
        st = np.zeros((n, 12), np.float64)
        if n == 0:
            return st
        r = region_stats(lab, n).astype(np.float64)
        st[:, _N], st[:, _SI], st[:, _SJ] = r[:, 0], r[:, 1], r[:, 2]
        st[:, _SK] = r[:, 0] * k
        st[:, _I0], st[:, _J0], st[:, _I1], st[:, _J1] = r[:, 3], r[:, 4], r[:, 5], r[:, 6]
        st[:, _K0] = k
        st[:, _K1] = k
        edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        edge = edge[edge >= 0]
        st[edge, _OPEN] = 1.0
        if plate:
            st[:, _PLATE] = 1.0
        return st

    def _emit(self, row: np.ndarray) -> None:
        if row[_OPEN]:
            return
        g = self.grid
        px, py = g.pixel_size
        h = g.layer_height
        n = row[_N]
        ci, cj, ck = row[_SI] / n, row[_SJ] / n, row[_SK] / n
        bbox = tuple(int(row[c]) for c in (_I0, _J0, _K0, _I1, _J1, _K1))
        self.traps.append(Trap("plate" if row[_PLATE] else "closed", float(n * px * py * h), int(n),
                               float(g.origin[0] + ci * px), float(g.origin[1] - cj * py),
                               float(g.origin[2] + ck * h), (bbox[2], bbox[5]), bbox))


def _combine(nodes: np.ndarray, inv: np.ndarray, n_groups: int) -> np.ndarray:
    """Bookkeeping of each group: sums add, minima and maxima (and the flags) combine."""
    out = np.zeros((n_groups, 12), np.float64)
    for c in _SUMS:
        out[:, c] = np.bincount(inv, weights=nodes[:, c], minlength=n_groups)
    for c in _MINS:
        out[:, c] = np.inf
        np.minimum.at(out[:, c], inv, nodes[:, c])
    for c in _MAXS:
        out[:, c] = -np.inf
        np.maximum.at(out[:, c], inv, nodes[:, c])
    return out


__all__ = ["Trap", "TrapFinder"]
