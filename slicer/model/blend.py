"""Blend operators: how the segments' fields combine into one field.

``sum``
    The paper's summation blending, ``F = sum_i f_i``: struts merge smoothly,
    and where many meet the field adds up, so the surface near a
    high-valence node lies outside every strut's own surface (a "bulge").
``union``
    ``F = max_i f_i``: every strut keeps its own surface ``f_i = 1``, so the
    solid is the union of the per-strut solids; the printed radius near a node
    is the designed one. For one strut both are the same field.

Slicing traces both, every voxel centre classified exactly as ``F >= 1`` in
float64 point evaluation (:func:`slicer.model.field.evaluate`). The union is traced
strut by strut (:mod:`slicer._kernels.trace.union`): along a ray each strut's
own field is unimodal on its support interval, so its inside centres are found
by splitting pieces at centres until a per-strut bound settles them, and the
struts' runs (and, with ``--aa-z``, their real inside spans) are merged. This
is the union inclusion read per strut: on a piece where each ``f_i`` lies in
``[lo_i, hi_i]``, ``max_i f_i`` lies in ``[max_i lo_i, max_i hi_i]``, so the
piece is inside as soon as one strut's low bound exceeds 1 and outside only
when every strut's high bound is below 1 (docs/math.md §5.4). Methods
``interval`` and ``sampling`` trace the union; ``segment`` (steps on the summed
field's Lipschitz bound) is refused. The renderer and the contour outputs
(which refine vertices on the summed field) refuse ``union`` with
:class:`~slicer.errors.OptionError` rather than show or write a summation.
"""
from __future__ import annotations

from slicer.arguments import choice
from slicer.errors import OptionError

#: blend names
BLENDS = ("sum", "union")
#: what the tracer's kernels implement
TRACER_BLENDS = ("sum", "union")
#: tracing methods that implement ``union``
UNION_METHODS = ("interval", "sampling")


def check_blend(blend, name: str = "--blend") -> str:
    """``blend`` as one of :data:`BLENDS`, else :class:`OptionError`.

    Examples
    --------
    >>> check_blend("Union")
    'union'
    """
    return choice(blend, BLENDS, name)


def require_traceable(blend, what: str = "slicing", method: str | None = None) -> str:
    """``blend`` checked for the tracer (and ``method``, when given).

    Raises
    ------
    OptionError
        For an unknown blend, or ``union`` with a method other than
        :data:`UNION_METHODS`.

    Examples
    --------
    >>> require_traceable("union", method="interval")
    'union'
    """
    b = check_blend(blend)
    if b not in TRACER_BLENDS:          # pragma: no cover - every blend is traceable today
        raise OptionError(f"--blend {b}: {what} does not support this blend")
    if b == "union" and method is not None and method not in UNION_METHODS:
        raise OptionError(f"--blend union: {what} with --method {method} is not supported (segment tracing steps "
                          f"on the summed field's Lipschitz bound); use --method interval or --method sampling")
    return b


def require_sum(blend, what: str, hint: str | None = None) -> str:
    """Refuse ``union`` where only the summed field is implemented (``what``:
    the renderer, the contour outputs; ``hint``: the way out, default
    ``--blend sum``).

    Raises
    ------
    OptionError
        For ``union``, naming ``what`` and the way out.

    Examples
    --------
    >>> require_sum("sum", "rendering")
    'sum'
    """
    b = check_blend(blend)
    if b != "sum":
        hint = hint or ("use --blend sum there (slicing to images and printer formats supports "
                        "--blend union)")
        raise OptionError(f"--blend {b}: {what} evaluates the summed field only and does not support the union "
                          f"blend; {hint}")
    return b


__all__ = ["BLENDS", "TRACER_BLENDS", "UNION_METHODS", "check_blend", "require_traceable", "require_sum"]
