"""The scene model: a skeleton of tapered segments and its kernel.

A :class:`Skeleton` is a structure of arrays. It is validated once, when it is
built; everything downstream (field, buckets, tracer) trusts it and hands its
contiguous arrays straight to the compiled kernels.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from slicer.errors import SceneError
from slicer.model.field import evaluate
from slicer.model.siis_kernel import DEFAULT_DEGREE, DEFAULT_SIGMA, MAX_DEGREE, kernel_normalisation
from slicer.scene.write import scene_document, write_scene


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Segments with linearly varying radius, blended by summation.

    The solid is ``{p : F(p) >= 1}`` with ``F`` the sum over segments of the
    scale-invariant integral field (docs/math.md §1).

    Parameters
    ----------
    nodes : (n, 3) float64, mm
        Node positions.
    segments : (m, 2) int64
        Node indices of each segment's two ends.
    radii : (m, 2) float64, mm
        Radius at each end of each segment (``radii[i, 0]`` at
        ``nodes[segments[i, 0]]``).
    degree : int, default 6
        Even kernel degree n.
    sigma : float, default 2.0
        Kernel support factor (support radius is ``sigma * radius``), > 1.

    Raises
    ------
    SceneError
        On wrong shapes, non-finite numbers, radius <= 0, indices out of
        range, zero-length segments or an invalid kernel; the message names
        the entry and the value.

    Examples
    --------
    >>> s = Skeleton([[0, 0, 0], [0, 0, 10]], [[0, 1]], [[1.0, 1.0]])
    >>> round(float(s.field([[1.0, 0.0, 5.0]])[0]), 9)
    1.0
    """

    nodes: np.ndarray
    segments: np.ndarray
    radii: np.ndarray
    degree: int = DEFAULT_DEGREE
    sigma: float = DEFAULT_SIGMA
    source: str | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        src = self.source
        nodes = _as_float_array(self.nodes, "nodes", src)
        if nodes.ndim != 2 or nodes.shape[1] != 3:
            raise SceneError(f"'nodes' must have shape (n, 3), got {nodes.shape}", src)
        segments = np.asarray(self.segments)
        if segments.size == 0:
            segments = segments.reshape(0, 2)
        if segments.ndim != 2 or segments.shape[1] != 2:
            raise SceneError(f"'segments' must have shape (m, 2), got {segments.shape}", src)
        if segments.dtype.kind == "f":
            bad = np.nonzero(segments != np.floor(segments))[0]
            if bad.size:
                i = int(bad[0])
                raise SceneError(f"segments[{i}] has a non-integer index: {segments[i].tolist()}", src)
        elif segments.dtype.kind not in "iu":
            raise SceneError(f"'segments' must hold integers, got dtype {segments.dtype}", src)
        segments = np.ascontiguousarray(segments, dtype=np.int64)
        radii = _as_float_array(self.radii, "radii", src)
        if radii.shape != segments.shape:
            raise SceneError(
                f"'radii' must have shape (m, 2) = {segments.shape} (one radius at each end "
                f"of each segment), got {radii.shape}", src)
        n = nodes.shape[0]
        bad = np.nonzero((segments < 0) | (segments >= n))
        if bad[0].size:
            i, j = int(bad[0][0]), int(bad[1][0])
            raise SceneError(
                f"segments[{i}][{j}] = {int(segments[i, j])} is out of range (there are {n} nodes)", src)
        bad = np.nonzero(~(radii > 0))
        if bad[0].size:
            i, j = int(bad[0][0]), int(bad[1][0])
            raise SceneError(f"radius at end {j} of segment {i} is {radii[i, j]!r}; radii must be > 0", src)
        if segments.shape[0]:
            length = np.linalg.norm(nodes[segments[:, 1]] - nodes[segments[:, 0]], axis=1)
            bad = np.nonzero(~(length > 0))[0]
            if bad.size:
                i = int(bad[0])
                raise SceneError(
                    f"segment {i} ({int(segments[i, 0])}, {int(segments[i, 1])}) has zero length", src)
        deg = self.degree
        if isinstance(deg, bool) or not isinstance(deg, (int, np.integer)) or deg < 2 or deg % 2 or deg > MAX_DEGREE:
            raise SceneError(f"kernel degree must be an even integer in [2, {MAX_DEGREE}], got {deg!r}", src)
        sig = self.sigma
        if isinstance(sig, bool) or not isinstance(sig, (int, float, np.floating, np.integer)) \
                or not np.isfinite(sig) or sig <= 1.0:
            raise SceneError(f"kernel sigma must be a finite number > 1, got {sig!r}", src)
        object.__setattr__(self, "nodes", nodes)
        object.__setattr__(self, "segments", segments)
        object.__setattr__(self, "radii", radii)
        object.__setattr__(self, "degree", int(deg))
        object.__setattr__(self, "sigma", float(sig))
        for a in (nodes, segments, radii):
            a.setflags(write=False)

    # ------------------------------------------------------------------ basics
    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return int(self.nodes.shape[0])

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return int(self.segments.shape[0])

    @cached_property
    def normalisation(self) -> float:
        """Kernel normalisation N for iso-value 1 (see :func:`kernel_normalisation`)."""
        return kernel_normalisation(self.degree, self.sigma)

    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """Segment end points.

        Returns
        -------
        a, b : (m, 3) float64, mm
        """
        return self.nodes[self.segments[:, 0]], self.nodes[self.segments[:, 1]]

    def support_bounds(self) -> np.ndarray:
        """Axis-aligned box of the union of all supports (radius ``sigma * tau``).

        The surface ``F = 1`` lies strictly inside it.

        Returns
        -------
        (2, 3) float64, mm
            ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
        """
        if self.n_segments == 0:
            raise SceneError("the scene has no segments", self.source)
        a, b = self.endpoints()
        ra = self.sigma * self.radii[:, :1]
        rb = self.sigma * self.radii[:, 1:]
        lo = np.minimum(a - ra, b - rb).min(axis=0)
        hi = np.maximum(a + ra, b + rb).max(axis=0)
        return np.array([lo, hi])

    def scaled(self, k: float) -> "Skeleton":
        """The same skeleton scaled by ``k`` about the origin (nodes and radii).

        The SIIS is scale invariant: the surface of the result is the surface
        of ``self`` scaled by ``k``.
        """
        return Skeleton(self.nodes * k, self.segments, self.radii * k, self.degree, self.sigma)

    def translated(self, offset) -> "Skeleton":
        """The same skeleton moved by ``offset`` ((3,) float64, mm)."""
        off = np.asarray(offset, dtype=np.float64).reshape(3)
        return Skeleton(self.nodes + off, self.segments, self.radii, self.degree, self.sigma)

    # ------------------------------------------------------------------ field
    def field(self, points) -> np.ndarray:
        """Field value F at points (inside means ``F >= 1``).

        Parameters
        ----------
        points : (k, 3) float64, mm

        Returns
        -------
        (k,) float64
        """
        return evaluate(self, points)[0]

    def gradient(self, points) -> np.ndarray:
        """Field gradient at points.

        Parameters
        ----------
        points : (k, 3) float64, mm

        Returns
        -------
        (k, 3) float64, 1/mm
        """
        return evaluate(self, points, gradient=True)[1]

    # ------------------------------------------------------------------ I/O
    def save(self, path) -> None:
        """Write the scene as JSON (version 1, ``segment_radii`` form), atomically."""
        write_scene(self, path)

    def to_dict(self) -> dict[str, Any]:
        """The scene as a JSON-ready dict (scene format version 1, :func:`slicer.scene.write.scene_document`)."""
        return scene_document(self)


def _as_float_array(value, name: str, src: str | None) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SceneError(f"'{name}' must be an array of numbers ({exc})", src) from None
    if arr.size and not np.all(np.isfinite(arr)):
        idx = np.argwhere(~np.isfinite(arr))[0]
        where = "".join(f"[{int(i)}]" for i in idx)
        raise SceneError(f"{name}{where} is not finite: {arr[tuple(idx)]!r}", src)
    if arr.size == 0 and name == "nodes":
        arr = arr.reshape(0, 3)
    return np.ascontiguousarray(arr)


__all__ = ["Skeleton", "kernel_normalisation", "DEFAULT_DEGREE", "DEFAULT_SIGMA", "MAX_DEGREE"]
