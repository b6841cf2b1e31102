"""Helpers shared by the run-length encoded printer formats (GOO, CTB, Anycubic).

* :func:`runs`: the runs of equal values of a row-major image, scanning only
  the rows that hold the model.
* :func:`split_runs`: runs cut to a format's longest run.
* :class:`GreyLevels`: the grey values a format can store and the nearest
  stored value of every 8-bit grey.
"""
from __future__ import annotations

import numpy as np


def runs(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of equal values of a row-major image: (values (r,) uint8, lengths (r,) int64).

    Only the band of rows with a non-zero pixel is scanned; the empty rows
    above and below join the first and last runs.

    Examples
    --------
    >>> v, n = runs(np.array([[0, 0, 7], [7, 0, 0], [0, 0, 0]], np.uint8))
    >>> v.tolist(), n.tolist()
    ([0, 7, 0], [2, 2, 5])
    """
    H, W = image.shape
    band = np.flatnonzero(image.any(axis=1))
    if band.size == 0:
        return np.zeros(1 if H * W else 0, np.uint8), np.full(1 if H * W else 0, H * W, np.int64)
    r0, r1 = int(band[0]), int(band[-1]) + 1
    flat = np.ascontiguousarray(image[r0:r1], dtype=np.uint8).reshape(-1)
    starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
    lengths = np.diff(np.concatenate([starts, [flat.size]])).astype(np.int64)
    vals = flat[starts]
    before, after = r0 * W, (H - r1) * W
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


__all__ = ["runs", "split_runs", "GreyLevels"]
