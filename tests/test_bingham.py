"""The Bingham distribution on S^3: operations against independent computations."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core import quaternion as quat
from core.bingham import Bingham, composition_inertia
from core.normalization import moments_jacobian
from sphere_quadrature import sphere_grid

RNG = np.random.default_rng(2024)


def random_bingham(z3, rng=RNG):
    return Bingham.from_mode(quat.normalize(rng.normal(size=4)), z3)


def sphere_integral(f, nodes=70):
    """Integral of f(x) over S^3 by brute-force quadrature (x: (K, 4))."""
    x, w = sphere_grid(4, nodes)
    return float(np.sum(w * f(x.T)))


def uniform_points(n, rng):
    x = rng.standard_normal((n, 4))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.mark.parametrize("z3", [[-3.0, -2.0, -1.0], [-20.0, -8.0, -8.0], [0.0, 0.0, 0.0]])
def test_pdf_integrates_to_one(z3):
    B = random_bingham(z3)
    assert abs(sphere_integral(lambda x: B.pdf(x, "exact")) - 1.0) < 1e-8


def test_pdf_is_antipodal_and_peaks_at_mode():
    B = random_bingham([-30.0, -10.0, -5.0])
    x = uniform_points(1000, RNG)
    np.testing.assert_allclose(B.pdf(x), B.pdf(-x))
    assert np.all(B.pdf(B.mode) >= B.pdf(x))


@pytest.mark.parametrize("z3", [[-3.0, -2.0, -1.0], [-40.0, -8.0, -0.5]])
def test_inertia_matches_sphere_integral(z3):
    B = random_bingham(z3)
    S = np.array([[sphere_integral(lambda x, i=i, j=j: x[:, i] * x[:, j] * B.pdf(x, "exact")) for j in range(4)] for i in range(4)])
    np.testing.assert_allclose(B.inertia("exact"), S, atol=1e-8)


def test_from_mode_puts_concentration_on_body_axes():
    q = quat.normalize([0.3, -0.2, 0.9, 0.1])
    B = Bingham.from_mode(q, [-1000.0, -10.0, -100.0])
    np.testing.assert_allclose(B.mode, q if q[0] >= 0 else -q, atol=1e-12)
    # a small rotation about body x is 100x less likely than about body y
    for axis, z in ((0, -1000.0), (1, -10.0), (2, -100.0)):
        d = quat.from_rotvec(0.05 * np.eye(3)[axis])
        expected = z * math.sin(0.025) ** 2
        assert abs(B.log_pdf(quat.multiply(q, d)) - B.log_pdf(q) - expected) < 1e-9


# -- fitting ------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["saddlepoint", "exact"])
@pytest.mark.parametrize("z3", [[-1e6, -1e6, -1e6], [-1e5, -2.0, -0.3], [-500.0, -500.0, -10.0], [-4.0, -2.0, -1.0], [-1e-3, -1e-3, -1e-3]])
def test_fit_of_inertia_recovers_distribution(method, z3):
    B = random_bingham(z3)
    F = Bingham.fit(B.inertia(method), method)
    np.testing.assert_allclose(F.Z, B.Z, rtol=1e-3, atol=1e-6)
    # C = M Z M^T is the whole distribution, whatever basis repeated entries get
    np.testing.assert_allclose(F.C, B.C, atol=1e-3 * np.abs(B.Z).max() + 1e-6)
    assert quat.angular_distance(F.mode, B.mode) < 1e-6


def test_from_samples_of_exact_draws():
    B = random_bingham([-200.0, -50.0, -10.0])
    F = Bingham.from_samples(B.sample(200_000, 1), method="exact")
    np.testing.assert_allclose(F.Z, B.Z, rtol=0.02)
    assert quat.angular_distance(F.mode, B.mode) < 0.01


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.eye(4) / 4 + np.triu(np.ones((4, 4)), 1) * 0.01, "symmetric"),
        (np.diag([-0.1, 0.3, 0.3, 0.5]), "semidefinite"),
        (np.eye(4) / 2, "trace"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.eye(3) / 3, "4x4"),
    ],
)
def test_fit_rejects_bad_inertia(bad, message):
    with pytest.raises(ValueError, match=message):
        Bingham.fit(bad)


@pytest.mark.parametrize(
    "M, Z, message",
    [
        (np.eye(4), [0.0, -1.0, -2.0, 0.0], "sorted"),
        (np.eye(4) * 2, [-3.0, -2.0, -1.0, 0.0], "orthogonal"),
        (np.eye(4), [np.nan, -2.0, -1.0, 0.0], "finite"),
    ],
)
def test_constructor_rejects_bad_parameters(M, Z, message):
    with pytest.raises(ValueError, match=message):
        Bingham(M, Z)


def test_bad_quaternions_raise():
    B = Bingham.uniform()
    with pytest.raises(ValueError, match="unit"):
        B.pdf([1.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="NaN"):
        B.rotate_left([np.nan, 0, 0, 1])
    with pytest.raises(ValueError):
        Bingham.from_samples(np.array([[1.0, 0, 0, 0]]), weights=[-1.0])


# -- operations -----------------------------------------------------------------------

def test_product_is_the_normalized_product_of_densities():
    A, B = random_bingham([-30.0, -5.0, -1.0]), random_bingham([-8.0, -8.0, -2.0])
    P = A.product(B)
    x = uniform_points(500, RNG)
    diff = P.log_pdf(x, "exact") - A.log_pdf(x, "exact") - B.log_pdf(x, "exact")
    np.testing.assert_allclose(diff, diff[0], atol=1e-9)
    assert abs(sphere_integral(lambda y: P.pdf(y, "exact")) - 1.0) < 1e-8


def test_rotations_and_inverse_transform_the_density():
    B = random_bingham([-30.0, -5.0, -1.0])
    u = quat.normalize(RNG.normal(size=4))
    x = uniform_points(300, RNG)
    np.testing.assert_allclose(B.rotate_left(u).pdf(quat.multiply(u, x)), B.pdf(x), rtol=1e-10)
    np.testing.assert_allclose(B.rotate_right(u).pdf(quat.multiply(x, u)), B.pdf(x), rtol=1e-10)
    np.testing.assert_allclose(B.inverse().pdf(quat.conjugate(x)), B.pdf(x), rtol=1e-10)


def test_composition_inertia_equals_all_pairs_average():
    """Bilinearity makes the formula exact for empirical inertias: averaging
    q_i (x) r_j over all pairs must give composition_inertia of the averages."""
    q, r = uniform_points(300, RNG) * [3, 1, 0.5, 0.2], uniform_points(250, RNG) * [0.3, 2, 1, 0.1]
    q, r = quat.normalize(q), quat.normalize(r)
    s = quat.multiply(q[:, None, :], r[None, :, :]).reshape(-1, 4)
    np.testing.assert_allclose(composition_inertia(q.T @ q / len(q), r.T @ r / len(r)), s.T @ s / len(s), atol=1e-14)


@pytest.mark.parametrize("method", ["saddlepoint", "exact"])
def test_compose_matches_monte_carlo(method):
    A, B = random_bingham([-60.0, -20.0, -5.0]), random_bingham([-100.0, -100.0, -30.0])
    s = quat.multiply(A.sample(200_000, 3), B.sample(200_000, 4))
    C = A.compose(B, method)
    S_mc = s.T @ s / len(s)
    tol = 0.01 if method == "exact" else 0.06  # saddlepoint: plus its moment error
    evals = np.linalg.eigvalsh(S_mc)
    assert np.all(np.abs(np.sort(C.moments(method)) - evals) < tol * evals + 4 / math.sqrt(len(s)) * np.sqrt(evals))
    assert quat.angular_distance(C.mode, Bingham.fit(S_mc, "exact").mode) < 0.01


@pytest.mark.parametrize("method", ["saddlepoint", "exact"])
@pytest.mark.parametrize("state_z", [[-3e3, -2e3, -500.0], [-1e6, -1e6, -3.0], [-5.0, -5.0, -3.0], [0.0, 0.0, 0.0]])
@pytest.mark.parametrize("noise_z", [-1e7, -2e3, -10.0, -0.5])
def test_isotropic_noise_shortcut_equals_the_tensor_composition(method, state_z, noise_z):
    """compose() with isotropic noise (``a S + b (I - S)``, warm-started fit) equals the general
    structure-tensor composition followed by a fresh fit, from uniform to very peaked."""
    A, W = random_bingham(state_z), Bingham.from_mode(quat.IDENTITY, [noise_z] * 3)
    assert W._isotropic_spread == noise_z
    general = Bingham.fit(composition_inertia(A.inertia(method), W.inertia(method)), method)
    fast = A.compose(W, method)
    np.testing.assert_allclose(fast.inertia(method), general.inertia(method), atol=1e-9)
    np.testing.assert_allclose(fast.Z, general.Z, rtol=1e-6, atol=1e-6)


def test_entropy_and_kl_match_monte_carlo():
    A, B = random_bingham([-40.0, -10.0, -2.0]), random_bingham([-15.0, -9.0, -1.0])
    x = A.sample(400_000, 5)
    la, lb = A.log_pdf(x, "exact"), B.log_pdf(x, "exact")
    se = 4 * np.std(la) / math.sqrt(len(x))
    assert abs(A.entropy("exact") + la.mean()) < se
    assert abs(A.kl_divergence(B, "exact") - (la - lb).mean()) < 4 * np.std(la - lb) / math.sqrt(len(x))
    assert abs(A.kl_divergence(A, "exact")) < 1e-12
    assert abs(Bingham.uniform().entropy("exact") - math.log(2 * math.pi**2)) < 1e-12


# -- sampling -----------------------------------------------------------------------------

@pytest.mark.parametrize("z3", [[-1e6, -1e6, -1e6], [-1e5, -3.0, -0.2], [-40.0, -8.0, -0.5], [0.0, 0.0, 0.0]])
def test_random_samples_have_exact_second_and_fourth_moments(z3):
    B = random_bingham(z3)
    n = 200_000
    y = B.sample(n, 11) @ B.M  # coordinates in the eigenbasis
    assert y.shape == (n, 4)
    m, jac = moments_jacobian(B.Z, "exact")
    fourth = jac + np.outer(m, m)
    y2 = y * y
    se2 = np.std(y2, axis=0) / math.sqrt(n)
    np.testing.assert_array_less(np.abs(y2.mean(axis=0) - m), 5 * se2 + 1e-15)
    emp4 = y2.T @ y2 / n
    se4 = np.sqrt(np.maximum((y2[:, :, None] * y2[:, None, :]).var(axis=0), 1e-300) / n)
    np.testing.assert_array_less(np.abs(emp4 - fourth), 5 * se4 + 1e-15)
    off = (y[:, 0] * y[:, 1]).mean()  # odd moments vanish
    assert abs(off) < 5 * np.std(y[:, 0] * y[:, 1]) / math.sqrt(n) + 1e-15


def test_sampling_is_reproducible_with_a_seed():
    B = random_bingham([-5.0, -2.0, -1.0])
    np.testing.assert_array_equal(B.sample(100, 42), B.sample(100, 42))


@pytest.mark.parametrize("lam", [0.0, 0.3, 0.5, 0.9])
@pytest.mark.parametrize("z3", [[-1e6, -1e4, -1.0], [-30.0, -10.0, -2.0], [0.0, 0.0, 0.0]])
def test_unscented_samples_match_inertia(lam, z3):
    B = random_bingham(z3)
    for antipodal, count in ((True, 14), (False, 7)):
        pts, w = B.unscented_samples(lam, antipodal)
        assert pts.shape == (count, 4) and np.all(w >= 0) and abs(w.sum() - 1) < 1e-12
        np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose((pts * w[:, None]).T @ pts, B.inertia(), atol=1e-14)
    with pytest.raises(ValueError, match="lambda"):
        B.unscented_samples(1.0)


# -- robustness ---------------------------------------------------------------------

concentration = st.one_of(st.floats(-1e6, 0.0), st.sampled_from([0.0, -1e6, -1e-9]))


@settings(max_examples=60, deadline=None)
@given(st.lists(concentration, min_size=3, max_size=3), st.lists(concentration, min_size=3, max_size=3), st.integers(0, 2**32 - 1))
def test_operations_never_produce_nan(z_a, z_b, seed):
    rng = np.random.default_rng(seed)
    A, B = random_bingham(z_a, rng), random_bingham(z_b, rng)
    for C in (A.compose(B), A.product(B), Bingham.fit(A.inertia())):
        assert np.all(np.isfinite(C.Z)) and np.all(np.isfinite(C.M))
        np.testing.assert_allclose(C.M.T @ C.M, np.eye(4), atol=1e-9)
        assert np.isfinite(C.entropy()) and np.isfinite(C.log_normalizer())
    assert np.isfinite(A.kl_divergence(B))


def test_with_concentrations_keeps_the_axes_and_resorts():
    A = random_bingham([-50.0, -20.0, -5.0])
    B = A.with_concentrations([-1.0, -30.0, -5.0])  # z_1 now the weakest, z_2 the strongest
    np.testing.assert_array_equal(B.mode, A.mode)
    np.testing.assert_array_equal(B.Z, [-30.0, -5.0, -1.0, 0.0])
    np.testing.assert_array_equal(B.M[:, :3], A.M[:, [1, 2, 0]])
    with pytest.raises(ValueError):
        A.with_concentrations([1.0, -2.0, -3.0])
