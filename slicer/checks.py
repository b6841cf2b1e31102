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

from .errors import OptionError, SkelsliceError


def fmt_num(value) -> str:
    """A number as people read it: ``0.05``, ``1.2e+302``, ``12,345``, ``inf``.

    Integers of up to 15 digits are shown whole (with thousands separators),
    larger ones with 6 significant digits; a float as Python writes it when
    that is short, else with 6 significant digits.

    Examples
    --------
    >>> fmt_num(0.05), fmt_num(1.2e302), fmt_num(12345), fmt_num(10**300), fmt_num(0.1 + 0.2)
    ('0.05', '1.2e+302', '12,345', '1e+300', '0.3')
    """
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return repr(value)
    if isinstance(value, numbers.Integral):
        v = int(value)
        return f"{v:,}" if abs(v) < 10**15 else f"{float(v):.6g}"
    if isinstance(value, numbers.Real):
        v = float(value)
        r = repr(v)
        return r if len(r) <= 12 else f"{v:.6g}"
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


__all__ = ["fmt_num", "number", "positive_number", "integer", "vector", "choice"]
