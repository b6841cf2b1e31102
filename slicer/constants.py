"""Tolerances: the one place where the slacks, pads and error budgets of the slicer are set.

Each constant says what it bounds and why its value is safe; the modules that use them import them from
here (compiled kernels too: a change here starts a fresh compiled cache for every kernel group, see
:mod:`slicer._jit`). docs/math.md §3–§5 derives the bounds these pads protect.
"""
from __future__ import annotations

# -- verdicts from bounds (compiled kernels) -------------------------------------------------------------

#: relative pad of every verdict "F > 1" / "F < 1" from bounds: a bound must clear 1 by
#: ``PAD * (1 + |bound|)``, far above the rounding of the summed field
PAD = 1e-10
#: ``|F - 1|`` below this at both ends of a piece holding no voxel centre is rounding noise: crossings are not
#: refined there (a pixel column lying in the surface of a constant-radius strut)
SURFACE_BAND = 1e-9
#: relative slack on every computed bound of the guaranteed contours' discs (rounding of a few dozen
#: operations is ~1e-15)
BOUND_SLACK = 1e-9
#: relative margin of the support test of point evaluation (the rounding of its few operations is ~1e-15)
REACH_SLACK = 1e-9

# -- the field and the contours ----------------------------------------------------------------------------

#: relative error budget of one closed-form field evaluation (docs/math.md §2.6 and the stiff-case suite:
#: ~1e-13)
FIELD_SLACK = 1e-9
#: smallest contour tolerance as a multiple of the float64 spacing at the scene's coordinates
TOL_ULPS = 1024

# -- rendering -----------------------------------------------------------------------------------------------

#: default crossing tolerance of the renderer, fraction of the support box diagonal
RENDER_TOLERANCE = 1e-4

# -- inputs and outputs --------------------------------------------------------------------------------------

#: relative tolerance on the singular values of a 3MF build item's similarity transform
SIMILARITY_RTOL = 1e-5
#: tolerance on square pixels of Photon files of version 1 (one pixel-size field), relative
SQUARE_TOLERANCE = 0.01

# -- validation ----------------------------------------------------------------------------------------------

#: slack for floating-point noise in the validation's distance checks, mm
DISTANCE_SLACK = 1e-9
#: voxels of the stiff suite with ``|F - 1|`` at most this are not counted as mismatches (summation order)
STIFF_FIELD_TOL = 1e-9
#: contour tolerance of the error-against-time reference, mm
REFERENCE_CONTOUR_TOL = 1e-5
