"""Blend operators: how the segments' fields combine into one field.

``sum``
    The paper's summation blending, ``F = sum_i f_i``: struts merge smoothly,
    and where many meet the field adds up, so the surface near a
    high-valence node lies outside every strut's own surface (a "bulge").
``union``
    ``F = max_i f_i``: every strut keeps its own surface ``f_i = 1``, so the
    solid is the union of the per-strut solids; the printed radius near a node
    is the designed one. For one strut both are the same field.

Sound interval inclusions for ``union`` are direct: on a piece of a ray, the
range of ``max_i f_i`` lies in ``[max_i lo_i, max_i hi_i]`` when each ``f_i``
lies in ``[lo_i, hi_i]``. Point evaluation (:func:`slicer.field.evaluate`)
supports both; the tracer, renderer and contours support ``sum`` only for
now, and refuse ``union`` with :class:`~slicer.errors.OptionError` rather
than print a summation.
"""
from __future__ import annotations

from .checks import choice
from .errors import OptionError

#: blend names
BLENDS = ("sum", "union")
#: what the tracer's kernels implement today
TRACER_BLENDS = ("sum",)


def check_blend(blend, name: str = "--blend") -> str:
    """``blend`` as one of :data:`BLENDS`, else :class:`OptionError`.

    Examples
    --------
    >>> check_blend("Union")
    'union'
    """
    return choice(blend, BLENDS, name)


def require_traceable(blend, what: str = "slicing") -> str:
    """Refuse a blend the ray kernels cannot trace yet.

    Raises
    ------
    OptionError
        For ``union``: naming what is missing (the union inclusion in the
        tracer's and renderer's per-piece bounds).

    Examples
    --------
    >>> require_traceable("sum")
    'sum'
    """
    b = check_blend(blend)
    if b not in TRACER_BLENDS:
        raise OptionError(f"--blend {b}: {what} with the union blend needs the ray kernels' union inclusion "
                          f"(the maximum of the per-segment interval bounds on each piece: max of the lows, max "
                          f"of the highs), which this version of the tracer does not have yet; use --blend sum, "
                          f"or evaluate the union field at points (slicer.field.evaluate(..., blend='union'))")
    return b


__all__ = ["BLENDS", "TRACER_BLENDS", "check_blend", "require_traceable"]
