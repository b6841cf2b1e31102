"""Helpers shared by the run-length encoded printer formats (GOO, CTB, Anycubic).

* :func:`occupied`: the box of an image's non-zero pixels.
* :class:`Band`: the rows of an image that hold the model, contiguous; the
  rest of a printer's plate is zero and never copied or scanned again.
* :func:`runs`: the runs of equal values of a row-major image (or band),
  scanning only the rows that hold the model.
* :func:`split_runs`: runs cut to a format's longest run.
* :class:`GreyLevels`: the grey values a format can store and the nearest
  stored value of every 8-bit grey.
"""
from __future__ import annotations

import numpy as np


def occupied(image: np.ndarray) -> tuple[int, int, int, int] | None:
    """The smallest box ``(r0, r1, c0, c1)`` (half-open rows and columns)
    holding every non-zero pixel of a (h, w) image; None when it has none.

    One pass over the image's rows (fast on a row-major image), then one
    over the columns of the rows found. An image with a ``window`` attribute
    (``(r0, r1, c0, c1)``, outside which it is zero: a
    :class:`slicer.raster.antialias.PlateImage`) is scanned inside the window only.

    Examples
    --------
    >>> occupied(np.array([[0, 0, 0, 0], [0, 3, 0, 0], [0, 0, 9, 0]], np.uint8))
    (1, 3, 1, 3)
    >>> occupied(np.zeros((2, 2), np.uint8)) is None
    True
    """
    window = getattr(image, "window", None)
    if window is not None:
        R0, R1, C0, C1 = window
        box = occupied(np.asarray(image)[R0:R1, C0:C1]) if R1 > R0 and C1 > C0 else None
        return None if box is None else (box[0] + R0, box[1] + R0, box[2] + C0, box[3] + C0)
    rows = np.flatnonzero(image.any(axis=1))
    if rows.size == 0:
        return None
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    cols = np.flatnonzero(image[r0:r1].any(axis=0))
    return r0, r1, int(cols[0]), int(cols[-1]) + 1


class Band:
    """The rows ``r0 : r0 + len(rows)`` of a (H, W) uint8 image whose other
    rows are all zero, held as one contiguous array.

    Attributes
    ----------
    rows : (r, W) uint8, C-contiguous
    r0 : int
    shape : (H, W)
        The whole image's shape.
    cols : (c0, c1)
        Columns outside ``c0:c1`` are zero in every row of the band.
    """

    __slots__ = ("rows", "r0", "shape", "cols")

    def __init__(self, rows: np.ndarray, r0: int, shape: tuple[int, int], cols: tuple[int, int] | None = None):
        self.rows = rows
        self.r0 = int(r0)
        self.shape = (int(shape[0]), int(shape[1]))
        self.cols = (0, self.shape[1]) if cols is None else (int(cols[0]), int(cols[1]))

    @classmethod
    def of(cls, image: np.ndarray, box: tuple[int, int, int, int] | None | bool = False) -> "Band":
        """The band of ``image`` (any strides: a view of a plate is fine).

        Parameters
        ----------
        image : (H, W) uint8 array
        box : (r0, r1, c0, c1), None or False
            Where the non-zero pixels are, if known (:func:`occupied`): only
            that box of ``image`` is read. None: the image is all zero.
            False (default): found by scanning the image.
        """
        H, W = image.shape
        if box is False:
            box = occupied(image)
        if box is None:
            return cls(np.zeros((0, W), np.uint8), 0, (H, W))
        r0, r1, c0, c1 = box
        if c0 == 0 and c1 == W:
            rows = np.ascontiguousarray(image[r0:r1], dtype=np.uint8)
        else:
            rows = np.zeros((r1 - r0, W), np.uint8)
            rows[:, c0:c1] = image[r0:r1, c0:c1]
        return cls(rows, r0, (H, W), (c0, c1))

    def _apply(self, fn) -> "Band":
        """The band of ``fn(image)`` for an ``fn`` that maps 0 to 0, applied to
        the columns ``cols`` only (the rest stays zero)."""
        c0, c1 = self.cols
        if c0 == 0 and c1 == self.shape[1]:
            return Band(np.ascontiguousarray(fn(self.rows), dtype=np.uint8), self.r0, self.shape, self.cols)
        rows = np.zeros(self.rows.shape, np.uint8)      # (calloc: only the window's pages are touched)
        rows[:, c0:c1] = fn(self.rows[:, c0:c1])
        return Band(rows, self.r0, self.shape, self.cols)

    def map(self, table: np.ndarray) -> "Band":
        """The band of ``table[image]`` (``table[0]`` must be 0, so the rows
        outside the band stay zero)."""
        if table[0] != 0:
            raise ValueError("a band's table must map 0 to 0")
        return self._apply(lambda a: table[a])

    def where_at_least(self, level: int) -> "Band":
        """The band of ``(image >= level)`` as 0 / 1 (``level`` >= 1)."""
        if level < 1:
            raise ValueError("level must be at least 1")
        return self._apply(lambda a: (a >= level).astype(np.uint8))


def runs(image) -> tuple[np.ndarray, np.ndarray]:
    """Runs of equal values of a row-major image: (values (r,) uint8, lengths (r,) int64).

    Only the band of rows with a non-zero pixel is scanned (``image`` may be
    a :class:`Band`); the empty rows above and below join the first and last
    runs. Of a band, only its columns ``cols`` are read: each row's window
    is followed by one zero standing for the ``W - (c1 - c0)`` zeros between
    two windows, and a run's length counts those.

    Examples
    --------
    >>> v, n = runs(np.array([[0, 0, 7], [7, 0, 0], [0, 0, 0]], np.uint8))
    >>> v.tolist(), n.tolist()
    ([0, 7, 0], [2, 2, 5])
    """
    band = image if isinstance(image, Band) else Band.of(image)
    H, W = band.shape
    if band.rows.shape[0] == 0:
        return np.zeros(1 if H * W else 0, np.uint8), np.full(1 if H * W else 0, H * W, np.int64)
    r0, r1 = band.r0, band.r0 + band.rows.shape[0]
    c0, c1 = band.cols
    if c1 - c0 < W:
        q = c1 - c0 + 1                              # a row's window and its stand-in zero
        win = np.zeros((r1 - r0, q), np.uint8)
        win[:, :q - 1] = band.rows[:, c0:c1]
        flat = win.reshape(-1)[:-1]
    else:
        q = 0
        flat = band.rows.reshape(-1)
    starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
    ends = np.concatenate([starts[1:], [flat.size]])
    lengths = (ends - starts).astype(np.int64)
    if q:
        # stand-ins in [s, e): the multiples of q in (s, e], each W - q + 1 zeros
        lengths += (ends // q - starts // q) * (W - q)
    vals = flat[starts]
    before, after = r0 * W + c0, (H - r1) * W + (W - c1)
    if before:
        if vals[0] == 0:
            lengths[0] += before
        else:
            vals, lengths = np.concatenate([[0], vals]).astype(np.uint8), np.concatenate([[before], lengths])
    if after:
        if vals[-1] == 0:
            lengths[-1] += after
        else:
            vals, lengths = np.concatenate([vals, [0]]).astype(np.uint8), np.concatenate([lengths, [after]])
    return vals, lengths


def split_runs(values: np.ndarray, lengths: np.ndarray, limit) -> tuple[np.ndarray, np.ndarray]:
    """Cut every run into pieces of at most ``limit`` pixels (the last piece holds the rest).

    Parameters
    ----------
    values : (r,) array
    lengths : (r,) int64, > 0
    limit : int or (r,) int64
        Longest run per run (a scalar, or one limit per run).

    Returns
    -------
    values, lengths : (r',) arrays

    Examples
    --------
    >>> v, n = split_runs(np.array([3, 9]), np.array([5, 2]), 2)
    >>> v.tolist(), n.tolist()
    ([3, 3, 3, 9], [2, 2, 1, 2])
    """
    limit = np.broadcast_to(np.asarray(limit, np.int64), lengths.shape)
    pieces = -(-lengths // limit)
    if np.all(pieces == 1):
        return values, lengths
    vals = np.repeat(values, pieces)
    lim = np.repeat(limit, pieces)
    first = np.concatenate([[0], np.cumsum(pieces)[:-1]])
    piece = np.arange(vals.size) - np.repeat(first, pieces)       # index of the piece within its run
    rest = np.repeat(lengths, pieces) - piece * lim
    return vals, np.minimum(rest, lim)


class GreyLevels:
    """The grey values a format stores, and how an 8-bit grey is stored.

    Parameters
    ----------
    decoded : (n,) int
        The 8-bit grey a reader decodes from each code ``0 .. n - 1`` (code 0
        must decode to 0 and the largest code to 255).

    Attributes
    ----------
    code : (256,) uint8
        Code stored for each 8-bit grey: the code whose decoded grey is
        nearest (ties go to the brighter one).
    level : (256,) uint8
        The grey a reader gets back: ``decoded[code[g]]``; the identity on 0
        and 255, so binary layers are stored exactly.

    Examples
    --------
    >>> g = GreyLevels([0, 85, 170, 255])
    >>> g.level[[0, 42, 43, 128, 255]].tolist(), g.code[[0, 42, 43, 128, 255]].tolist()
    ([0, 0, 85, 170, 255], [0, 0, 1, 2, 3])
    """

    def __init__(self, decoded):
        dec = np.asarray(decoded, np.int64)
        if dec[0] != 0 or dec.max() != 255:
            raise ValueError("grey levels must decode code 0 to 0 and reach 255")
        g = np.arange(256)[:, None]
        dist = np.abs(dec[None, :] - g) * 2 - (dec[None, :] > g)      # ties: the brighter level wins
        self.code = np.argmin(dist, axis=1).astype(np.uint8)
        self.level = dec[self.code].astype(np.uint8)
        self.count = int(np.unique(dec).size)

    def __repr__(self) -> str:
        return f"GreyLevels({self.count} levels)"


__all__ = ["occupied", "Band", "runs", "split_runs", "GreyLevels"]
