"""Option and value checks: the one place where numbers from users are validated.

Every check returns the value in its working type or raises the error class it
is given (:class:`~slicer.errors.OptionError` by default), with a message that
names the option or entry and shows the value as a person would write it
(:func:`fmt_num`: ``1.2e+302``, never a 300-digit integer).
"""
from __future__ import annotations

import math
import numbers

import numpy as np

from slicer.errors import OptionError, SceneError, SkelsliceError

#: largest magnitude of any coordinate, radius, size, offset or time a scene or an option may
#: have (mm or s): squares and kernel powers of such numbers stay far inside float64
MAX_MAGNITUDE = 1e9
#: smallest radius a scene may have, mm (1 pm)
MIN_RADIUS = 1e-9
#: coordinates may be at most this many times the smallest radius (and the smallest grid step
#: or tolerance) from the origin: float64 then keeps about 7 significant digits below that
#: length (eps x 1e9 = 2.2e-7), which the tracer's exact classification of points, its span
#: tolerances and the contour projection rely on (docs/scene-format.md, "Limits")
RESOLUTION_RATIO = 1e9
#: largest number of voxels (or cells of a reference grid) a job may have
MAX_CELLS = 10**12
#: largest count option (bucket edges, threads, tiles): what compiled code's 32-bit ints hold
MAX_COUNT = 2**31 - 1


def fmt_num(value) -> str:
    """A number as people read it: ``0.05``, ``1.2e+302``, ``12,345``, ``inf``.

    Integers of up to 15 digits are shown whole (with thousands separators),
    larger ones with 6 significant digits; a float as Python writes it when
    that is short, else with 6 significant digits.

    Examples
    --------
    >>> fmt_num(0.05), fmt_num(1.2e302), fmt_num(12345), fmt_num(10**300), fmt_num(0.1 + 0.2)
    ('0.05', '1.2e+302', '12,345', '1e+300', '0.3')
    >>> fmt_num(-10**400), fmt_num(int("9" * 400))
    ('-1e+400', '9.99999e+399')
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, numbers.Integral):
        v = int(value)
        if abs(v) < 10**15:
            return f"{v:,}"
        try:
            return f"{float(v):.6g}"
        except OverflowError:                # beyond float range: the leading digits and the exponent
            sign = "-" if v < 0 else ""
            if abs(v).bit_length() >= 14_000:    # str() refuses more than 4,300 digits
                return f"{sign}an integer of {abs(v).bit_length():,} bits"
            d = str(abs(v))
            mantissa = (d[0] + "." + d[1:6]).rstrip("0").rstrip(".")
            return f"{sign}{mantissa}e+{len(d) - 1}"
    if isinstance(value, numbers.Real):
        v = float(value)
        r = repr(v)
        return r if len(r) <= 12 and not abs(v) >= 1e6 else f"{v:.6g}"
    return repr(value)


def _is_bool(value) -> bool:
    return isinstance(value, (bool, np.bool_))


def number(value, name: str, error: type[SkelsliceError] = OptionError, *, lo: float | None = None,
           hi: float | None = None, lo_open: bool = False, hi_open: bool = False, what: str = "a number") -> float:
    """``value`` as a finite float within ``[lo, hi]`` (either end open or absent).

    Raises
    ------
    error
        Not a real number (booleans and strings are refused), not finite, or
        out of range; the message names ``name`` and the value.

    Examples
    --------
    >>> number("0.5", "--gamma", lo=0, lo_open=True)
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --gamma must be a number > 0, got '0.5'
    >>> number(2, "--exposure", lo=0.1, hi=60)
    2.0
    """
    rng = _range_text(lo, hi, lo_open, hi_open)
    must = f"{name} must be {what}{rng}"
    finite = f"{name} must be {'a finite number' if what == 'a number' else what}{rng}"
    if _is_bool(value) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise error(f"{must}, got {value!r}")
    try:
        v = float(value)
    except OverflowError:            # an integer beyond float range
        raise error(f"{finite}, got {fmt_num(value)}") from None
    if not math.isfinite(v) or (lo is not None and (v <= lo if lo_open else v < lo)) \
            or (hi is not None and (v >= hi if hi_open else v > hi)):
        raise error(f"{finite}, got {fmt_num(value)}")
    return v


def positive_number(value, name: str, error: type[SkelsliceError] = OptionError) -> float:
    """``value`` as a finite float > 0, else ``error`` naming ``name`` and the value.

    Examples
    --------
    >>> positive_number(0.05, "--pixel-size")
    0.05
    >>> positive_number(True, "--pixel-size")
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --pixel-size must be a number > 0, got True
    """
    return number(value, name, error, lo=0.0, lo_open=True)


def integer(value, name: str, error: type[SkelsliceError] = OptionError, *, lo: int | None = None,
            hi: int | None = None) -> int:
    """``value`` as an int within ``[lo, hi]``; integral floats (``4.0``) are accepted.

    Examples
    --------
    >>> integer(4.0, "--aa", lo=1, hi=16)
    4
    >>> integer(2.5, "--aa", lo=1, hi=16)
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --aa must be an integer from 1 to 16, got 2.5
    """
    rng = (f" from {lo} to {hi}" if lo is not None and hi is not None else
           f" >= {lo}" if lo is not None else f" <= {hi}" if hi is not None else "")
    must = f"{name} must be an integer{rng}"
    if _is_bool(value) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
        raise error(f"{must}, got {value!r}")
    if isinstance(value, (numbers.Integral, np.integer)):
        v = int(value)
    else:
        f = float(value)
        if not math.isfinite(f) or f != math.floor(f):
            raise error(f"{must}, got {fmt_num(f)}")
        v = int(f)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise error(f"{must}, got {fmt_num(v)}")
    return v


def vector(value, n: int, name: str, error: type[SkelsliceError] = OptionError,
           max_abs: float | None = None) -> tuple[float, ...]:
    """``value`` as ``n`` finite floats (each at most ``max_abs`` in magnitude if given).

    Examples
    --------
    >>> vector([1, 2], 2, "--at")
    (1.0, 2.0)
    """
    try:
        items = list(value)
    except TypeError:
        raise error(f"{name} must be {n} numbers, got {value!r}") from None
    if len(items) != n:
        raise error(f"{name} must be {n} numbers, got {len(items)}")
    out = []
    for k, x in enumerate(items):
        v = number(x, f"{name}[{k}]", error)
        if max_abs is not None and abs(v) > max_abs:
            raise error(f"{name}[{k}] = {fmt_num(v)} is beyond the supported magnitude {fmt_num(max_abs)}")
        out.append(v)
    return tuple(out)


def magnitude(value, name: str, error: type[SkelsliceError] = OptionError, *, positive: bool = False,
              unit: str = "mm") -> float:
    """``value`` as a finite float of magnitude at most :data:`MAX_MAGNITUDE` (> 0 if ``positive``).

    For every number that places, sizes, offsets or times something (``--at``,
    ``--bounds``, sizes, tolerances, exposures, camera positions).

    Examples
    --------
    >>> magnitude(-3, "--at[0]")
    -3.0
    >>> magnitude(1e308, "--exposure", positive=True, unit="s")
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --exposure = 1e+308 s is beyond the supported magnitude 1e+09 s
    """
    v = positive_number(value, name, error) if positive else number(value, name, error)
    if abs(v) > MAX_MAGNITUDE:
        raise error(f"{name} = {fmt_num(v)} {unit} is beyond the supported magnitude {fmt_num(MAX_MAGNITUDE)} {unit}")
    return v


def coordinates(value, n: int, name: str, error: type[SkelsliceError] = OptionError) -> tuple[float, ...]:
    """``value`` as ``n`` finite floats, each of magnitude at most :data:`MAX_MAGNITUDE` (mm).

    Examples
    --------
    >>> coordinates((0, 1e300, 0), 3, "--eye")
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --eye[1] = 1e+300 is beyond the supported magnitude 1e+09
    """
    return vector(value, n, name, error, max_abs=MAX_MAGNITUDE)


def resolvable(value, name: str, reach: float, error: type[SkelsliceError] = OptionError) -> float:
    """A length (tolerance, mesh edge, step) that float64 resolves at coordinates up to ``reach`` mm.

    ``value`` must be a finite number > 0, at most :data:`MAX_MAGNITUDE`,
    and at least ``reach / RESOLUTION_RATIO`` (``reach``: the largest
    coordinate magnitude of the scene, mm).

    Examples
    --------
    >>> resolvable(1e-3, "--contour-tol", 11.0)
    0.001
    >>> resolvable(1e-300, "--contour-tol", 11.0)
    Traceback (most recent call last):
    ...
    slicer.errors.OptionError: --contour-tol = 1e-300 mm is below what float64 resolves at the scene's coordinates (up to 11.0 mm from the origin): it must be at least 1.1e-08 mm (1e-09 of that distance)
    """
    v = magnitude(value, name, error, positive=True)
    floor = float(reach) / RESOLUTION_RATIO
    if v < floor:
        raise error(f"{name} = {fmt_num(v)} mm is below what float64 resolves at the scene's coordinates "
                    f"(up to {fmt_num(float(reach))} mm from the origin): it must be at least "
                    f"{fmt_num(float(f'{floor:.2g}'))} mm ({1 / RESOLUTION_RATIO:g} of that distance)")
    return v


def scene_reach(scene) -> float:
    """The largest coordinate magnitude of a scene's support box, mm (a Skeleton or a Part:
    anything with ``support_bounds()``); the ``reach`` of :func:`resolvable`."""
    return float(np.max(np.abs(np.asarray(scene.support_bounds(), dtype=np.float64))))


def scene_step(value, name: str, scene, error: type[SkelsliceError] = OptionError) -> float:
    """A grid spacing over a whole scene (``validate --mesh-edge``): :func:`resolvable` at the
    scene's coordinates, and at most :data:`MAX_CELLS` cells over its support box.

    ``scene``: anything with ``support_bounds()`` (a Skeleton or a Part), mm.
    """
    box = np.asarray(scene.support_bounds(), dtype=np.float64)
    v = resolvable(value, name, float(np.max(np.abs(box))), error)
    cells = float(np.prod(np.floor(np.ptp(box, axis=0) / v) + 2.0))
    if cells > MAX_CELLS:
        raise error(f"{name} = {fmt_num(v)} mm would need {cells:.3g} grid cells over the scene's support box "
                    f"(limit {MAX_CELLS:.0e}); use a larger {name}")
    return v


def scene_numbers(nodes: np.ndarray, radii: np.ndarray, source: str | None = None, *,
                  node_entry=None, radius_entry=None) -> None:
    """Refuse a scene whose numbers float64 cannot handle exactly (docs/scene-format.md, "Limits").

    Every coordinate and radius must be finite and of magnitude at most
    :data:`MAX_MAGNITUDE` mm, every radius at least :data:`MIN_RADIUS` mm,
    and every coordinate at most :data:`RESOLUTION_RATIO` times the smallest
    radius from the origin.

    Parameters
    ----------
    nodes : (n, 3) float64, mm
    radii : (m, 2) float64, mm
        The radius at each end of each segment.
    source : str, optional
        The file (prefixed to the message).
    node_entry : callable (i, k) -> str, optional
        The name of coordinate ``k`` of node ``i`` in the file (default ``nodes[i][k]``).
    radius_entry : callable (i, j) -> str, optional
        The name of the radius at end ``j`` of segment ``i`` (default ``radius at end j of segment i``).

    Raises
    ------
    SceneError
        Naming the entry, its value and the limit.
    """
    node_entry = node_entry or (lambda i, k: f"nodes[{i}][{k}]")
    radius_entry = radius_entry or (lambda i, j: f"radius at end {j} of segment {i}")
    nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 3)
    radii = np.asarray(radii, dtype=np.float64).reshape(-1, 2)
    lim = fmt_num(MAX_MAGNITUDE)
    why = (f"float64 resolves a scene within these limits: |coordinate| and radius <= {lim} mm, "
           f"radius >= {fmt_num(MIN_RADIUS)} mm, |coordinate| <= {fmt_num(RESOLUTION_RATIO)} x the smallest radius")
    if nodes.size:
        big = np.abs(nodes)
        bad = np.argwhere(~(big <= MAX_MAGNITUDE))
        if bad.size:
            i, k = (int(x) for x in bad[0])
            raise SceneError(f"{node_entry(i, k)} = {fmt_num(nodes[i, k])} mm is beyond the supported magnitude "
                             f"{lim} mm ({why})", source)
    if radii.size:
        bad = np.argwhere(~(radii <= MAX_MAGNITUDE))
        if bad.size:
            i, j = (int(x) for x in bad[0])
            raise SceneError(f"{radius_entry(i, j)} = {fmt_num(radii[i, j])} mm is beyond the supported magnitude "
                             f"{lim} mm ({why})", source)
        bad = np.argwhere(~(radii >= MIN_RADIUS))
        if bad.size:
            i, j = (int(x) for x in bad[0])
            raise SceneError(f"{radius_entry(i, j)} = {fmt_num(radii[i, j])} mm is below the smallest supported "
                             f"radius {fmt_num(MIN_RADIUS)} mm ({why})", source)
        if nodes.size:
            i, j = (int(x) for x in np.unravel_index(np.argmin(radii), radii.shape))
            rmin = float(radii[i, j])
            n, k = (int(x) for x in np.unravel_index(np.argmax(big), big.shape))
            if big[n, k] > RESOLUTION_RATIO * rmin:
                raise SceneError(
                    f"{node_entry(n, k)} = {fmt_num(nodes[n, k])} mm is more than {fmt_num(RESOLUTION_RATIO)} times "
                    f"the smallest radius ({radius_entry(i, j)} = {fmt_num(rmin)} mm) from the origin: float64 cannot "
                    f"resolve that strut so far out; move the model near the origin or thicken it", source)


def choice(value, choices, name: str, error: type[SkelsliceError] = OptionError) -> str:
    """``value`` (case-insensitive) if it is one of ``choices``, else ``error`` listing them.

    Examples
    --------
    >>> choice("Interval", ("interval", "sampling"), "--method")
    'interval'
    """
    key = str(value).strip().lower()
    if key not in choices:
        raise error(f"unknown {name} {value!r}; choose one of {', '.join(sorted(choices))}")
    return key


def _range_text(lo, hi, lo_open, hi_open) -> str:
    b = lambda x: f"{x:g}"      # noqa: E731 - bounds are constants of the code: shortest form
    if lo is None and hi is None:
        return ""
    if lo is not None and hi is not None:
        if not lo_open and not hi_open:
            return f" from {b(lo)} to {b(hi)}"
        return f" in {'(' if lo_open else '['}{b(lo)}, {b(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f" {'>' if lo_open else '>='} {b(lo)}"
    return f" {'<' if hi_open else '<='} {b(hi)}"


__all__ = ["fmt_num", "number", "positive_number", "integer", "vector", "choice", "magnitude", "coordinates",
           "resolvable", "scene_numbers", "scene_reach", "scene_step", "MAX_CELLS", "MAX_COUNT", "MAX_MAGNITUDE", "MIN_RADIUS", "RESOLUTION_RATIO"]
