"""Supports and a pad for what the check calls unprintable (docs/supports.md).

:func:`slicer.supports.build.supported_scene` adds supports (a tapered head at
each support point, a pillar to the pad or the plate, or onto the model below)
and a pad to a model; the result is a :class:`~slicer.supports.groups.GroupedSkeleton`
whose model struts come first, unchanged but for a lift along z, and whose
support and pad struts unite with the model (:mod:`.groups`). Support points
come from the exact slices and the field (:mod:`.points`); renders and
reports of supported scenes are in :mod:`.show`, the command in :mod:`.cli`.

This package imports only :mod:`.groups` (the tracer uses it); import the
builder from :mod:`slicer.supports.build`.
"""
from __future__ import annotations

from slicer.supports.groups import ROLES, SUPPORT_ROLES, GroupedSkeleton, is_grouped

__all__ = ["GroupedSkeleton", "ROLES", "SUPPORT_ROLES", "is_grouped"]
