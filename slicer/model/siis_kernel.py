"""The SIIS kernel's parameters: degree, support factor and normalisation (docs/math.md §1.3)."""
from __future__ import annotations

#: default kernel degree n of k(d) = N (1 - (d/sigma)^2)^(n/2)
DEFAULT_DEGREE = 6
#: default support factor sigma (support radius = sigma * tau)
DEFAULT_SIGMA = 2.0
#: largest supported kernel degree (kernels use fixed-size scratch arrays)
MAX_DEGREE = 16


def kernel_normalisation(degree: int, sigma: float) -> float:
    """Normalisation N that puts the iso-value 1 at distance tau of a long strut.

    ``N = 1 / (sigma * B_m * (1 - 1/sigma^2)^((n+1)/2))`` with
    ``B_m = 2^(2m+1) (m!)^2 / (2m+1)!`` and ``m = n/2`` (docs/math.md §1.3).

    Parameters
    ----------
    degree : int
        Even kernel degree n >= 2.
    sigma : float
        Support factor, > 1.

    Returns
    -------
    float

    Examples
    --------
    >>> round(kernel_normalisation(6, 2.0), 10)
    1.4968340312
    """
    m = degree // 2
    b_m = 1.0
    # B_m = prod_{k=1..m} 2k/(2k+1) * 2
    for k in range(1, m + 1):
        b_m *= (2.0 * k) / (2.0 * k + 1.0)
    b_m *= 2.0
    return 1.0 / (sigma * b_m * (1.0 - 1.0 / sigma**2) ** ((degree + 1) / 2.0))


__all__ = ["DEFAULT_DEGREE", "DEFAULT_SIGMA", "MAX_DEGREE", "kernel_normalisation"]
