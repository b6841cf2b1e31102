"""Independent, slow reference for the SIIS field (re-export).

The reference lives in :mod:`validation.reference_field` (extended-precision
Gauss–Legendre quadrature of the definition; it imports nothing from
:mod:`slicer`). This module keeps ``import reference`` working for the tests.
"""
from validation.reference_field import *  # noqa: F401,F403
from validation.reference_field import __all__  # noqa: F401
