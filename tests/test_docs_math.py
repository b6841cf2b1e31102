"""docs/math.md says what the code computes: its tables are recomputed here.

Every numeric table of docs/math.md is parsed from the file and each printed
value is recomputed from the code (and, where the code is not the only
source, from an independent formula or an mpmath quadrature). A value passes
when it agrees to half a unit in its last printed digit (plus two ulp of
the value for rounding), so a wrong digit in the document fails the test.
The doctests of docs/math.md run here too.
"""
from __future__ import annotations

import doctest
import math
import re
from pathlib import Path

import numpy as np
import pytest

from slicer import Skeleton
from slicer.cli.commands.info import MIN_ISOLATED_LENGTH
from slicer.model.skeleton import DEFAULT_DEGREE, DEFAULT_SIGMA, kernel_normalisation
from slicer._kernels.field.segment import SCRATCH, SHORT_Z, _moments, _series_sum
from slicer._kernels.rays.support import kprime_abs, kprime_max
from validation.reference_field import normalisation as reference_normalisation

MATH = Path(__file__).resolve().parent.parent / "docs" / "math.md"


# --------------------------------------------------------------------------- parsing
def _tables(text: str) -> list[tuple[list[str], list[list[str]]]]:
    """Every markdown table: (header cells, rows of cells), cells stripped of ** and `."""
    out = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        if lines[i].startswith("|") and i + 1 < len(lines) and re.match(r"^\|(\s*-+\s*\|)+\s*$", lines[i + 1]):
            head = _cells(lines[i])
            rows = []
            i += 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            out.append((head, rows))
        else:
            i += 1
    return out


def _cells(line: str) -> list[str]:
    cells = [c.strip() for c in line.strip().strip("|").replace("\\|", "¦").split("|")]
    return [c.replace("**", "").replace("`", "").replace("¦", "|").replace("−", "-") for c in cells]


def _table(first_header: list[str]) -> list[list[str]]:
    found = [rows for head, rows in _tables(MATH.read_text(encoding="utf-8"))
             if head[:len(first_header)] == first_header]
    assert len(found) == 1, f"docs/math.md must hold exactly one table headed {first_header}"
    return found[0]


def _agrees(printed: str, value: float) -> bool:
    """``value`` rounds to the printed decimal (half a unit in its last digit, + 2 ulp)."""
    text = printed.strip()
    decimals = len(text.split(".")[1]) if "." in text else 0
    tol = 0.5 * 10.0 ** -decimals + 2 * np.spacing(abs(value))
    return abs(value - float(text)) <= tol


def _check(printed: str, value: float, what: str) -> None:
    assert _agrees(printed, value), f"docs/math.md prints {printed} for {what}; the code gives {value!r}"


# --------------------------------------------------------------------------- computations
def _bisect(fun, lo, hi, iters=90):
    """x in [lo, hi] with fun(x) = 1 (fun - 1 changes sign on [lo, hi])."""
    below = fun(lo) < 1.0
    assert (fun(hi) < 1.0) != below
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if (fun(mid) < 1.0) == below:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _argmax_kprime(n: int, sigma: float, norm: float) -> float:
    """Golden-section maximiser of the code's |k'| on (0, sigma)."""
    if n == 2:
        return sigma          # |k'| = 2 N d / sigma^2 grows up to the support edge
    g = (math.sqrt(5.0) - 1.0) / 2.0
    lo, hi = 0.0, sigma
    for _ in range(200):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if kprime_abs(x1, n, sigma, norm) >= kprime_abs(x2, n, sigma, norm):
            hi = x2
        else:
            lo = x1
    return 0.5 * (lo + hi)


def _long_strut(n=DEFAULT_DEGREE, sigma=DEFAULT_SIGMA):
    return Skeleton([[0, 0, 0], [0, 0, 40]], [[0, 1]], [[1.0, 1.0]], degree=n, sigma=sigma)


def _unit(L):
    return Skeleton([[0, 0, 0], [0, 0, L]], [[0, 1]], [[1.0, 1.0]])


def _free_end():
    s = _long_strut()
    return _bisect(lambda e: s.field([[0, 0, 40 + e]])[0], 0.0, 1.0)


def _min_isolated_length():
    return _bisect(lambda L: _unit(L).field([[0, 0, L / 2]])[0], 0.5, 1.0)


def _iso_radius(L):
    s = _unit(L)
    return _bisect(lambda r: s.field([[r, 0, L / 2]])[0], 0.0, 2.0)


# --------------------------------------------------------------------------- tests
def test_doctests_of_math_md():
    res = doctest.testfile(str(MATH), module_relative=False, optionflags=doctest.ELLIPSIS, verbose=False)
    assert res.attempted > 20
    assert res.failed == 0, f"{res.failed} doctest(s) of docs/math.md failed (run: python -m doctest docs/math.md)"


def test_kernel_constants_table():
    """§1.4: N, |k'|max, d*, the axis value and the surface slope per kernel."""
    rows = _table(["n", "σ", "N"])
    assert {(int(r[0]), float(r[1])) for r in rows} >= {(6, 2.0), (2, 2.0), (16, 1.2)}
    for n_s, s_s, N_s, kmax_s, dstar_s, axis_s, slope_s in rows:
        n, sigma = int(n_s), float(s_s)
        what = f"n = {n}, sigma = {sigma:g}"
        norm = kernel_normalisation(n, sigma)
        _check(N_s, norm, f"N ({what})")
        _check(N_s, reference_normalisation(n, sigma), f"N ({what}, Gamma-function form)")
        kmax = kprime_max(n, sigma, norm)
        _check(kmax_s, kmax, f"|k'|max ({what})")
        d = np.linspace(0.0, sigma, 2_000_001)[:-1]            # the support is open at sigma
        dense = norm * n * d / sigma**2 * (1 - d * d / sigma**2) ** (n // 2 - 1)
        # n = 2: the supremum is the limit at the support edge, one grid step away
        assert abs(dense.max() - kmax) <= (1e-9 if n > 2 else 2e-6) * kmax, what
        dstar = _argmax_kprime(n, sigma, norm)
        _check(dstar_s, dstar, f"d* ({what})")
        if n > 2:
            _check(dstar_s, sigma / math.sqrt(n - 1), f"d* = sigma/sqrt(n-1) ({what})")
        strut = _long_strut(n, sigma)
        _check(axis_s, strut.field([[0, 0, 20]])[0], f"F on the axis ({what})")
        _check(axis_s, (1 - 1 / sigma**2) ** (-(n + 1) / 2), f"F on the axis, closed form ({what})")
        slope = np.linalg.norm(strut.gradient([[1.0, 0, 20]])[0])
        _check(slope_s, slope, f"|grad F| tau at the surface ({what})")
        _check(slope_s, (n + 1) / (sigma**2 - 1), f"surface slope, closed form ({what})")


def test_surface_facts_table():
    """§1.5: free ends, short isolated segments."""
    N = kernel_normalisation(6, 2.0)
    prim = lambda v: v - v**3 / 4 + 3 * v**5 / 80 - v**7 / 448        # ∫_0^v (1 - u²/4)³ du  # noqa: E731
    compute = {
        "free_end": _free_end,
        "end_value": lambda: _long_strut().field([[0, 0, 40]])[0],
        "min_isolated_length": _min_isolated_length,
        "peak_half": lambda: _unit(0.5).field([[0, 0, 0.25]])[0],
        "iso_radius_1": lambda: _iso_radius(1.0),
        "iso_radius_2": lambda: _iso_radius(2.0),
        "iso_radius_4": lambda: _iso_radius(4.0),
    }
    closed = {
        "free_end": lambda: _bisect(lambda e: N * (prim(2.0) - prim(e)), 0.0, 1.0),
        "end_value": lambda: N * prim(2.0),
        "min_isolated_length": lambda: _bisect(lambda L: 2 * N * prim(L / 2), 0.5, 1.0),
        "peak_half": lambda: 2 * N * prim(0.25),
    }
    rows = _table(["name", "fact", "value"])
    assert sorted(r[0] for r in rows) == sorted(compute), "§1.5 must list exactly the checked facts"
    for name, what, value in rows:
        _check(value, compute[name](), f"{name} ({what})")
        if name in closed:
            _check(value, closed[name](), f"{name} ({what}), closed form")


def test_the_code_quotes_the_documented_minimum_length():
    """info's warning threshold is the §1.5 value, and that value is right to its digits."""
    assert f"{MIN_ISOLATED_LENGTH:g}" == "0.688"
    _check(f"{MIN_ISOLATED_LENGTH:g}", _min_isolated_length(), "the minimum isolated length")


def test_cone_iso_radius_table():
    """§1.5: iso-radius / tau(z) on a long cone, the same at every height."""
    rows = _table(["δ", "iso-radius / τ(z)"])
    assert len(rows) >= 5
    for d_s, ratio_s in rows:
        d = float(d_s)
        cone = Skeleton([[0, 0, 1.0], [0, 0, 400.0]], [[0, 1]], [[d * 1.0, d * 400.0]])
        for z in (30.0, 50.0, 70.0):
            r = _bisect(lambda r: cone.field([[r * d * z, 0, z]])[0], 0.5, 2.0)
            _check(ratio_s, r, f"the cone iso-radius ratio at delta = {d:g}, z = {z:g}")


_CONSTANTS = {
    "m": lambda: DEFAULT_DEGREE // 2,
    "B_3": lambda: 32 / 35,
    "N": lambda: kernel_normalisation(DEFAULT_DEGREE, DEFAULT_SIGMA),
    "c_if_N_is_1": lambda: 1 / kernel_normalisation(DEFAULT_DEGREE, DEFAULT_SIGMA),
    "support_radius": lambda: DEFAULT_SIGMA,
    "kprime_max": lambda: kprime_max(DEFAULT_DEGREE, DEFAULT_SIGMA, kernel_normalisation(6, 2.0)),
    "d_star": lambda: _argmax_kprime(DEFAULT_DEGREE, DEFAULT_SIGMA, kernel_normalisation(6, 2.0)),
    "axis_value": lambda: _long_strut().field([[0, 0, 20]])[0],
    "surface_slope": lambda: np.linalg.norm(_long_strut().gradient([[1.0, 0, 20]])[0]),
    "free_end": _free_end,
    "min_isolated_length": _min_isolated_length,
}


def test_constants_table():
    """§8: the default kernel's constants."""
    rows = _table(["name", "quantity", "value"])
    assert sorted(r[0] for r in rows) == sorted(_CONSTANTS), "§8 must list exactly the checked constants"
    b3 = 2**7 * math.factorial(3) ** 2 / math.factorial(7)
    assert b3 == 32 / 35
    for name, what, value in rows:
        _check(value, float(_CONSTANTS[name]()), f"{name} ({what})")


def _vec(text: str) -> tuple[float, ...]:
    return tuple(float(x) for x in text.strip("()").split(","))


def _mp_segment_field(p, a, b, t0, t1, degree=6, sigma=2.0):
    """The definition (§1.1) by mpmath quadrature at 30 digits, between the exact roots of
    the support quadratic in s (E s² - 2 G s + H < 0, §2.2)."""
    mp = pytest.importorskip("mpmath")
    with mp.workdps(30):
        p, a, b = ([mp.mpf(repr(float(x))) for x in v] for v in (p, a, b))
        t0, t1 = mp.mpf(repr(t0)), mp.mpf(repr(t1))
        D = [bi - ai for ai, bi in zip(a, b)]
        w = [pi - ai for pi, ai in zip(p, a)]
        L = mp.sqrt(sum(x * x for x in D))
        dt = t1 - t0
        E = L * L - sigma**2 * dt * dt
        G = sum(x * y for x, y in zip(D, w)) + sigma**2 * t0 * dt
        H = sum(x * x for x in w) - sigma**2 * t0 * t0
        cuts = [mp.mpf(0), mp.mpf(1)]
        disc = G * G - E * H
        if disc > 0 and E != 0:
            cuts += [r for r in ((G - mp.sqrt(disc)) / E, (G + mp.sqrt(disc)) / E) if 0 < r < 1]
        cuts = sorted(cuts)
        norm = 1 / (sigma * mp.beta(mp.mpf(1) / 2, mp.mpf(degree) / 2 + 1)
                    * (1 - mp.mpf(1) / sigma**2) ** (mp.mpf(degree + 1) / 2))

        def integrand(s):
            tau = t0 + s * dt
            d2 = sum((wi - s * Di) ** 2 for wi, Di in zip(w, D)) / (tau * tau)
            x = 1 - d2 / sigma**2
            return L / tau * x ** (degree // 2) if x > 0 else mp.mpf(0)

        return float(norm * mp.quad(integrand, cuts))


def test_reference_vectors():
    """§9: every printed digit of f agrees with an mpmath quadrature, the code's f
    agrees to 1e-14, and the code's gradient agrees to every printed digit."""
    rows = _table(["p", "a", "b", "τ0", "τ1", "f", "∇f"])
    assert len(rows) >= 6
    for p_s, a_s, b_s, t0_s, t1_s, f_s, g_s in rows:
        p, a, b = _vec(p_s), _vec(a_s), _vec(b_s)
        t0, t1 = float(t0_s), float(t1_s)
        what = f"p = {p_s}, a = {a_s}, b = {b_s}, radii {t0_s} .. {t1_s}"
        _check(f_s, _mp_segment_field(p, a, b, t0, t1), f"f (mpmath), {what}")
        sk = Skeleton([a, b], [[0, 1]], [[t0, t1]])
        f = sk.field([p])[0]
        assert abs(f - float(f_s)) <= 1e-14 * abs(float(f_s)), (what, f, f_s)
        g = sk.gradient([p])[0]
        for gi, s in zip(g, g_s.strip("()").split(",")):
            _check(s.strip(), gi, f"the gradient, {what}")


def test_moments_against_mpmath():
    """§2.4: the moments J_j = ∫_0^Y y^j / (1 - δ y) dy of ``_moments`` for z = δY from
    1e-12 to 0.999, degrees 6 and 16, against a 30-digit mpmath quadrature."""
    mp = pytest.importorskip("mpmath")
    rng = np.random.default_rng(7)
    worst = 0.0
    for nmax in (6, 16):
        for z in np.concatenate([10.0 ** rng.uniform(-12, -0.3, 40), 1 - 10.0 ** rng.uniform(-3, -0.3, 20),
                                 [0.5, 0.5 + 1e-12, 0.7711, 0.7712]]):
            Y = float(rng.uniform(0.05, 3.0))
            d = float(z / Y)
            l = Y / (1 - d * Y)
            w = np.zeros(SCRATCH)
            for j in range(nmax + 2):
                w[51 + j] = Y**j
            _moments(Y, d, l, nmax, w, 34, 51)
            with mp.workdps(30):
                for j in range(nmax + 1):
                    ref = mp.quad(lambda y: y**j / (1 - d * y), [0, Y])
                    worst = max(worst, abs(w[34 + j] - float(ref)) / float(ref))
    assert worst < 5e-14, worst


def test_series_sum_short_form_against_mpmath():
    """§2.4: the moment series ``sum_k z^k / (n + 1 + k)`` to a few ulps for every degree,
    on both sides of ``SHORT_Z`` (below it: a fixed number of terms by Estrin's scheme;
    above: term by term), and exactly 1/(n + 1) at z = 0 (an untapered strut)."""
    mp = pytest.importorskip("mpmath")
    rng = np.random.default_rng(11)
    zs = np.concatenate([10.0 ** rng.uniform(-12, math.log10(SHORT_Z), 60),
                         [SHORT_Z, np.nextafter(SHORT_Z, 1.0), 0.07, 0.2, 0.5]])
    worst = 0.0
    for nmax in range(2, 17, 2):
        assert _series_sum(0.0, nmax) == 1.0 / (nmax + 1)
        for z in zs:
            with mp.workdps(40):
                ref = mp.nsum(lambda k: mp.mpf(float(z)) ** k / (nmax + 1 + k), [0, mp.inf])
            worst = max(worst, abs(_series_sum(float(z), nmax) - float(ref)) / float(ref))
    assert worst < 4 * np.finfo(float).eps, worst
