"""Normalization constant and moments, against independent computations.

* ``method="exact"`` against a brute-force integral over the sphere, against
  finite differences of itself (moments are d log N / dz), and against the
  Laplace asymptote when extremely concentrated;
* ``method="saddlepoint"`` against ``"exact"`` over a grid from uniform to
  |z| = 1e6, with the error bounds measured and reported in the README;
* the Gauss-Newton fit as the inverse of the moments.
"""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core import normalization as nz
from sphere_quadrature import brute_force, importance_moments, sphere_area

MODERATE = [
    np.zeros(4),
    np.array([-1.0, -2.0, -3.0, 0.0]),
    np.array([-10.0, -10.0, -10.0, 0.0]),
    np.array([-30.0, -1.0, -12.0, 0.0]),
    np.array([-3.0, 2.0, 5.0, 1.0]),  # positive entries, unsorted
    np.array([-7.0, -7.0, 0.0, 0.0]),
]


@pytest.mark.parametrize("z", MODERATE, ids=str)
def test_exact_matches_brute_force_integral(z):
    log_ref, mom_ref = brute_force(z, nodes=120)
    log_n, mom = nz.log_normalizer(z, "exact"), nz.moments(z, "exact")
    assert abs(math.expm1(log_n - log_ref)) < 1e-6
    np.testing.assert_allclose(mom, mom_ref, rtol=1e-6)


@pytest.mark.parametrize("z", [np.array([-4.0, 0.0]), np.array([3.0, -1.0, 2.0]), np.array([-20.0, -5.0, 0.0])], ids=str)
def test_exact_low_dimensions_match_brute_force(z):
    log_ref, mom_ref = brute_force(z, nodes=200)
    assert abs(math.expm1(nz.log_normalizer(z, "exact") - log_ref)) < 1e-6
    np.testing.assert_allclose(nz.moments(z, "exact"), mom_ref, rtol=1e-6)


@pytest.mark.parametrize("n", [2, 3, 4, 6, 8])
def test_uniform(n):
    """At Z = 0 the exact value is the sphere's area, and the saddlepoint reduces
    to Stirling's series for Gamma(n/2) with the 1/(12a) term (T = -1/(12a))."""
    a = n / 2
    stirling = 0.5 * math.log(2 * math.pi / a) + a * math.log(a / math.e) + 1 / (12 * a)
    expected_sp = math.log(sphere_area(n)) + math.lgamma(a) - stirling
    assert abs(nz.log_normalizer(np.zeros(n)) - expected_sp) < 1e-12
    np.testing.assert_allclose(nz.moments(np.zeros(n)), np.full(n, 1.0 / n), rtol=1e-12)
    if n <= 4:
        assert abs(nz.log_normalizer(np.zeros(n), "exact") - math.log(sphere_area(n))) < 1e-12
        np.testing.assert_allclose(nz.moments(np.zeros(n), "exact"), np.full(n, 1.0 / n), rtol=1e-12)


@pytest.mark.parametrize("method", nz.METHODS)
def test_shift_identity_eq3(method):
    z = np.array([-40.0, -7.0, -2.5, 0.0])
    for c in (-1e5, -3.0, 2.0, 1e5):
        assert abs(nz.log_normalizer(z + c, method) - nz.log_normalizer(z, method) - c) < 1e-9 * (1 + abs(c))
        np.testing.assert_allclose(nz.moments(z + c, method), nz.moments(z, method), rtol=1e-9)


@pytest.mark.parametrize("z", [np.array([-1.0, -2.0, -3.0, 0.0]), np.array([-500.0, -40.0, -0.5, 0.0])], ids=str)
def test_exact_moments_are_the_gradient_of_log_n(z):
    h = 1e-5 * (1 + np.abs(z))
    grad = [(nz.log_normalizer(z + h[i] * e, "exact") - nz.log_normalizer(z - h[i] * e, "exact")) / (2 * h[i]) for i, e in enumerate(np.eye(4))]
    np.testing.assert_allclose(nz.moments(z, "exact"), grad, rtol=1e-6)


def test_exact_jacobian_matches_finite_differences():
    z = np.array([-30.0, -8.0, -1.0, 0.0])
    _, jac = nz.moments_jacobian(z, "exact")
    h = 1e-5
    fd = np.column_stack([(nz.moments(z + h * e, "exact") - nz.moments(z - h * e, "exact")) / (2 * h) for e in np.eye(4)])
    np.testing.assert_allclose(jac, fd, atol=1e-9)


@pytest.mark.parametrize("z", [np.array([-1e4, -2e4, -5e4, 0.0]), np.array([-1e6, -1e6, -1e6, 0.0]), np.array([-1e5, -3e5, -1e6, 0.0])], ids=str)
def test_exact_matches_laplace_when_concentrated(z):
    lam = -z[:3]
    laplace = math.log(2 * math.pi**1.5) - 0.5 * np.log(lam).sum()
    tol = 2.0 * np.sum(1.0 / lam)  # relative error of Laplace is O(sum 1/lambda)
    assert abs(nz.log_normalizer(z, "exact") - laplace) < tol
    np.testing.assert_allclose(nz.moments(z, "exact")[:3], 0.5 / lam, rtol=tol)


@pytest.mark.parametrize("z", [np.array([-0.5, -1.0, -4.0, 0.0]), np.array([-20.0, -3.0, -3.0, 0.0])], ids=str)
def test_moments_match_monte_carlo(z):
    mc, se = importance_moments(z, 400_000, np.random.default_rng(7))
    for method in nz.METHODS:
        err = np.abs(nz.moments(z, method) - mc)
        bound = 5 * se if method == "exact" else 5 * se + 0.06 * mc  # saddlepoint: its measured error on top
        assert np.all(err < bound), (method, err, se)


# -- the saddlepoint approximation against exact --------------------------------

GRID_VALUES = [0.0, 0.1, 0.5, 1, 2, 3, 5, 8, 10, 20, 50, 100, 1e3, 1e4, 1e5, 1e6]
GRID = [-np.array([c, b, a, 0.0]) for a, b, c in itertools.combinations_with_replacement(GRID_VALUES, 3)]


def saddlepoint_errors(z):
    exact_log, exact_mom = nz.log_normalizer(z, "exact"), nz.moments(z, "exact")
    n_err = math.expm1(nz.log_normalizer(z) - exact_log)
    m_err = np.max(np.abs(nz.moments(z)[:3] / exact_mom[:3] - 1.0))
    return n_err, m_err


def test_saddlepoint_error_over_grid():
    """Measured worst case over the 816-point grid (README "Accuracy").

    The bounds are what Kume-Wood's third-order approximation achieves here,
    not the issue's 3% / 2% targets, which this approximation cannot meet:
    its error peaks at 6.4% (N) and 5.2% (moments) near z = -(5, 5, 3, 0).
    """
    errs = np.array([saddlepoint_errors(z) for z in GRID])
    assert np.all(np.isfinite(errs))
    assert np.max(np.abs(errs[:, 0])) < 0.065
    assert np.max(errs[:, 1]) < 0.053


def test_saddlepoint_accurate_in_the_limits():
    """Near uniform the error is Stirling's for Gamma(2); concentrated, it tends to
    Stirling's error for Gamma(1/2) (one free axis, a chi-square with one degree)."""
    n_err, m_err = saddlepoint_errors(np.array([-1e-3, -2e-3, -1e-3, 0.0]))
    assert abs(n_err) < 4e-4 and m_err < 1e-6
    half_stirling = 0.5 * math.log(4 * math.pi) + 0.5 * math.log(0.5 / math.e) + 1 / 6
    limit = math.expm1(math.lgamma(0.5) - half_stirling)  # -1.317%
    n_err, m_err = saddlepoint_errors(np.array([-1e6, -2e5, -1e5, 0.0]))
    assert abs(n_err - limit) < 1e-4 and m_err < 0.0125


@pytest.mark.parametrize("z", [np.array([-200.0, -50.0, -20.0, 0.0]), np.array([-5.0, -5.0, -3.0, 0.0])], ids=str)
def test_saddlepoint_jacobian_matches_exact(z):
    """Eq. 4 with |k| = 2 gives d m_i / d z_j within the approximation's error,
    and the Jacobian keeps the exact identities: rows and columns sum to 0."""
    _, jac_exact = nz.moments_jacobian(z, "exact")
    _, jac_sp = nz.moments_jacobian(z, "saddlepoint")
    # measured: 1.3% of the largest entry at the first z, 7.2% at the second (the grid's worst region)
    np.testing.assert_allclose(jac_sp, jac_exact, atol=0.08 * np.abs(jac_exact).max())
    np.testing.assert_allclose(jac_sp.sum(axis=0), 0, atol=1e-12)
    np.testing.assert_allclose(jac_sp.sum(axis=1), 0, atol=1e-12)


# -- robustness ----------------------------------------------------------------

z_entry = st.one_of(st.floats(-1e6, 1e3), st.sampled_from([0.0, -1e6, -1e-9, -1.0]))


@settings(max_examples=300, deadline=None)
@given(st.lists(z_entry, min_size=4, max_size=4))
def test_saddlepoint_never_fails(z):
    z = np.array(z)
    log_n = nz.log_normalizer(z)
    m, jac = nz.moments_jacobian(z)
    assert np.isfinite(log_n) and np.all(np.isfinite(m)) and np.all(np.isfinite(jac))
    assert np.all(m > 0) and abs(m.sum() - 1) < 1e-12


@settings(max_examples=40, deadline=None)
@given(st.lists(z_entry, min_size=4, max_size=4))
def test_exact_never_fails(z):
    z = np.array(z)
    log_n, m = nz.log_normalizer(z, "exact"), nz.moments(z, "exact")
    assert np.isfinite(log_n) and np.all(np.isfinite(m)) and np.all(m >= 0) and abs(m.sum() - 1) < 1e-9


@pytest.mark.parametrize("bad", [[np.nan, 0, 0, 0], [np.inf, 0, 0, 0], [[0.0]], [1.0]])
def test_bad_z_raises(bad):
    with pytest.raises(ValueError):
        nz.log_normalizer(bad)


def test_unknown_method_raises():
    with pytest.raises(ValueError, match="method"):
        nz.moments(np.zeros(4), method="lookup")


@pytest.mark.parametrize("bad", [[0.5, 0.2, 0.2, 0.1], [0.1, 0.2, 0.3, 0.5], [np.nan, 0.2, 0.3, 0.5]])
def test_fit_rejects_bad_targets(bad):
    with pytest.raises(ValueError):
        nz.fit_dispersion(bad)


# -- fitting: the inverse of the moments -----------------------------------------

FIT_CASES = [g for g in GRID if np.all((g == 0) | (g <= -0.1))][::7] + [np.array([-1e6, -1e6, -1e6, 0.0]), np.array([-1e-3, -1e-3, -2e-3, 0.0])]


@pytest.mark.parametrize("method", nz.METHODS)
def test_fit_inverts_moments(method):
    cases = FIT_CASES if method == "saddlepoint" else FIT_CASES[::4]
    for z in cases:
        z = np.sort(z)
        fitted = nz.fit_dispersion(nz.moments(z, method), method)
        np.testing.assert_allclose(fitted, z, rtol=1e-3, atol=1e-6, err_msg=f"{method} {z}")


def test_fit_of_degenerate_moments_is_finite():
    z = nz.fit_dispersion([0.0, 0.0, 0.0, 1.0])
    assert np.all(np.isfinite(z)) and z[0] < -1e8
