"""The compiled per-tick kernels against the numpy forms they replace (and closed forms).

Inputs: random states and exponents over the concentrations a filter meets
(near uniform, |z| ~ 1, to very peaked, |z| ~ 1e9), and the edge cases of an
eigendecomposition (repeated eigenvalues, a matrix already diagonal, zero).
"""

import math

import numpy as np
import pytest

from core import bingham_kernels as kernels
from core import quaternion as quat
from core import saddlepoint
from core.bingham import Bingham, composition_inertia
from core.filters import rms_angle_deg
from core.normalization import MIN_MOMENT, fit_dispersion_trusted, moments, moments_trusted
from core.observations import heading_exponent, vector_exponent
from fuser.model.velocity import tilt_doubt_deg
from fuser.model_error import _widened_one, widened_concentrations, with_model_error

RNG_SEEDS = range(40)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A random 4x4 orthogonal matrix (QR of a Gaussian matrix, signs fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(4, 4)))
    return q * np.sign(np.diag(r))


def random_state(rng: np.random.Generator, scale: float) -> Bingham:
    z = np.sort(-scale * rng.uniform(0.0, 1.0, size=3))
    return Bingham.from_mode(quat.normalize(rng.normal(size=4)), z)


def symmetric_cases():
    """(name, matrix): random spectra over twelve decades, and the repeated, diagonal and zero edge cases."""
    rng = np.random.default_rng(1)
    for seed in RNG_SEEDS:
        scale = 10.0 ** rng.uniform(-3, 9)
        Q = random_rotation(rng)
        yield f"random-{seed}", (Q * (scale * rng.normal(size=4))) @ Q.T
    Q = random_rotation(rng)
    yield "pairs", (Q * np.array([-2e4, -2e4, 0.0, 0.0])) @ Q.T  # a gravity reading on a uniform prior
    yield "triple", (Q * np.array([-5.0, 3.0, 3.0, 3.0])) @ Q.T
    yield "all-equal", 7.0 * np.eye(4)
    yield "zero", np.zeros((4, 4))
    yield "diagonal", np.diag([3.0, -1.0, 2.0, -1e6])
    yield "near-repeated", (Q * np.array([-1e6, -1e6 * (1 + 1e-12), -3.0, 0.0])) @ Q.T
    yield "davenport", vector_exponent(np.array([0.1, -0.2, 0.97]), np.array([0.0, 0.0, 1.0]), 0.01)


@pytest.mark.parametrize("name,a", list(symmetric_cases()), ids=lambda x: x if isinstance(x, str) else "")
def test_symmetric_eigh_matches_numpy(name, a):
    a = 0.5 * (a + a.T)
    evals, evecs = kernels.symmetric_eigh(a)
    ref_vals, ref_vecs = np.linalg.eigh(a)
    size = max(np.abs(ref_vals).max(), 1e-300)
    assert np.all(np.isfinite(evals)) and np.all(np.isfinite(evecs))
    assert np.all(np.diff(evals) >= 0.0)
    np.testing.assert_allclose(evals, ref_vals, rtol=0, atol=1e-13 * size)
    np.testing.assert_allclose(evecs.T @ evecs, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(a @ evecs, evecs * evals, rtol=0, atol=1e-13 * size)
    # each eigenspace (equal eigenvalues grouped) spans what numpy's does: equal projectors
    groups = np.split(np.arange(4), np.flatnonzero(np.diff(ref_vals) > 1e-9 * size) + 1)
    for g in groups:
        np.testing.assert_allclose(evecs[:, g] @ evecs[:, g].T, ref_vecs[:, g] @ ref_vecs[:, g].T, atol=1e-9)


def test_symmetric_eigh_is_a_function_of_the_input_bits():
    a = np.diag([1.0, 1.0, -2.0, -2.0])  # repeated: any basis would do, the same one must come every time
    first = kernels.symmetric_eigh(a)
    assert all(np.array_equal(first[1], kernels.symmetric_eigh(a)[1]) for _ in range(3))
    np.testing.assert_array_equal(first[0], [-2.0, -2.0, 1.0, 1.0])


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_product_parameters_is_the_eigendecomposition_of_the_summed_exponent(seed):
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(-2, 7))
    C = vector_exponent(rng.normal(size=3), rng.normal(size=3), 10.0 ** rng.uniform(-3, 0))
    evals, evecs = kernels.product_parameters(state.M, state.Z, C)
    exponent = state.M @ np.diag(state.Z) @ state.M.T + C
    ref = np.linalg.eigvalsh(exponent)
    size = np.abs(ref).max()
    np.testing.assert_allclose(evals, ref, atol=1e-12 * size)
    np.testing.assert_allclose(evecs @ np.diag(evals) @ evecs.T, exponent, atol=1e-12 * size)
    product = state.times_exponent(C)  # the Bingham built from it: the mode is the top eigenvector
    top = np.linalg.eigh(exponent)[1][:, -1]
    assert abs(abs(product.mode @ top) - 1.0) < 1e-9


@pytest.mark.parametrize("seed", range(10))
def test_rotations_are_the_quaternion_matrices(seed):
    rng = np.random.default_rng(seed)
    M = random_rotation(rng)
    u = quat.normalize(rng.normal(size=4))
    np.testing.assert_allclose(kernels.rotated_right(u, M), quat.right_matrix(u) @ M, atol=1e-15)
    np.testing.assert_allclose(kernels.rotated_left(u, M), quat.left_matrix(u) @ M, atol=1e-15)
    for j in range(4):  # closed form: each column is the Hamilton product
        np.testing.assert_allclose(kernels.rotated_right(u, M)[:, j], quat.multiply(M[:, j], u), atol=1e-15)
        np.testing.assert_allclose(kernels.rotated_left(u, M)[:, j], quat.multiply(u, M[:, j]), atol=1e-15)


def test_rotation_keeps_the_moments_it_had_computed():
    b = Bingham.from_mode(quat.IDENTITY, [-300.0, -200.0, -5.0])
    u = quat.from_rotvec(np.array([0.3, -0.1, 0.2]))
    before = b.moments()
    rotated = b.rotate_right(u)
    np.testing.assert_array_equal(rotated.moments(), before)
    np.testing.assert_allclose(rotated.moments(), moments(rotated.Z), rtol=1e-15)
    np.testing.assert_allclose(b.rotate_left(u).mode, quat.multiply(u, b.mode) * np.sign(quat.multiply(u, b.mode)[0]), atol=1e-15)


@pytest.mark.parametrize("z3", [[-3.0, -1.0, -2.0], [-1.0, -1.0, -1.0], [0.0, -5.0, 0.0], [-1e9, -1e-9, -4.0]])
def test_sorted_concentrations_is_a_stable_argsort(z3):
    M = random_rotation(np.random.default_rng(3))
    z3 = np.array(z3)
    out, Z, ok = kernels.sorted_concentrations(M, z3)
    order = np.argsort(z3, kind="stable")
    assert ok
    np.testing.assert_array_equal(out, np.column_stack([M[:, order], M[:, 3]]))
    np.testing.assert_array_equal(Z, np.append(z3[order], 0.0))


@pytest.mark.parametrize("bad", [[1.0, -1.0, -1.0], [math.nan, -1.0, -1.0], [-math.inf, -1.0, -1.0]])
def test_sorted_concentrations_refuses_what_is_not_a_concentration(bad):
    assert not kernels.sorted_concentrations(np.eye(4), np.array(bad))[2]
    with pytest.raises(ValueError):
        Bingham.uniform().with_concentrations(bad)


Z_CASES = [np.zeros(4), np.array([-1e-6, -1e-6, 0.0, 0.0]), np.array([-1.0, -1.0, -1.0, 0.0]),
           np.array([-5.0, -5.0, -3.0, 0.0]), np.array([-2e4, -2e4, 0.0, 0.0]), np.array([-1e9, -4e8, -2e3, 0.0]),
           np.array([-1e9, -1e9, -1e9, 0.0])]


@pytest.mark.parametrize("z", Z_CASES, ids=lambda z: str(z.tolist()))
def test_saddlepoint_moments_match_the_derivatives(z):
    g = saddlepoint.derivatives(z, 1)[1]
    m = saddlepoint.moments(z)
    np.testing.assert_allclose(m, g / g.sum(), rtol=1e-15)
    assert np.all(np.isfinite(m)) and abs(m.sum() - 1.0) < 1e-14
    if z[0] == 0.0:
        np.testing.assert_allclose(m, 0.25, rtol=1e-12)  # uniform, by symmetry
    if z[0] <= -1e8:  # peaked: E[y_i^2] -> 1/(2|z_i|), to the approximation's 1.3% there (core.normalization)
        np.testing.assert_allclose(m[:3], 0.5 / np.abs(z[:3]), rtol=0.015)


def _fit_numpy(target, start):
    """The numpy form fit_moments replaced (fit_dispersion_trusted before it was compiled)."""
    t = np.maximum(target, MIN_MOMENT)
    t /= t.sum()
    z0 = 0.5 / t[-1] - 0.5 / t if start is None else np.array(start)
    z, m = saddlepoint.fit_log_moments(z0, np.log(t), 1e-20, 60)
    order = np.argsort(z, kind="stable")
    return z[order], m[order]


@pytest.mark.parametrize("z", Z_CASES, ids=lambda z: str(z.tolist()))
@pytest.mark.parametrize("with_start", [False, True])
def test_fit_moments_matches_the_numpy_fit_and_inverts_the_moments(z, with_start):
    target = moments_trusted(z, "saddlepoint")
    start = np.minimum(z * 0.9, 0.0) if with_start else None
    fitted_z, fitted_m = fit_dispersion_trusted(target, "saddlepoint", start)
    ref_z, ref_m = _fit_numpy(target, start)
    np.testing.assert_allclose(fitted_z, ref_z, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fitted_m, ref_m, rtol=1e-12)
    assert np.all(np.isfinite(fitted_z)) and np.all(np.diff(fitted_z) >= 0) and abs(fitted_z[-1]) < 1e-12
    np.testing.assert_allclose(fitted_m, target, rtol=1e-8)  # the moments it was asked for
    np.testing.assert_allclose(fitted_z, z, rtol=1e-6, atol=1e-6)


def test_fit_moments_raises_degenerate_moments_to_the_floor():
    z, m = fit_dispersion_trusted(np.array([0.0, 0.0, 0.0, 1.0]), "saddlepoint")
    assert np.all(np.isfinite(z)) and np.all(z[:3] < -1e8)  # capped at about 1 / (2 MIN_MOMENT)
    np.testing.assert_allclose(z, _fit_numpy(np.array([0.0, 0.0, 0.0, 1.0]), None)[0], rtol=1e-12)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_compose_with_isotropic_noise_matches_the_tensor_form(seed):
    """The per-tick prediction's moment match against the general composition (QBF paper, A.9) of the same inertia."""
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(0, 6))
    noise = Bingham.from_mode(quat.IDENTITY, [-2.0 / 10.0 ** rng.uniform(-8, -3)] * 3)
    fast = state.compose(noise)
    S = composition_inertia(state.inertia(), noise.inertia())
    general = Bingham._fit_trusted(0.5 * (S + S.T), "saddlepoint")
    np.testing.assert_allclose(fast.inertia(), general.inertia(), atol=1e-12)
    np.testing.assert_allclose(fast.Z, general.Z, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_widened_one_matches_the_vectorised_widening(seed):
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(-2, 9))
    tilt, heading = 10.0 ** rng.uniform(-8, -2, size=2)
    np.testing.assert_allclose(_widened_one(state.M, state.Z, tilt, heading), widened_concentrations(state.M, state.Z, tilt, heading),
                               rtol=1e-14)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_with_model_error_is_the_widened_bingham(seed):
    """The compiled consider term (``(M, Z)`` in and out) is the Bingham with the widened concentrations, re-sorted
    (:meth:`core.bingham.Bingham.with_concentrations`, the form it replaced), and widens every axis it knows."""
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(-2, 9))
    tilt, heading = 10.0 ** rng.uniform(-8, -2, size=2)
    M, Z = with_model_error(state.M, state.Z, tilt, heading)
    ref = state.with_concentrations(widened_concentrations(state.M, state.Z, tilt, heading))
    np.testing.assert_array_equal(M, ref.M)
    np.testing.assert_allclose(Z, ref.Z, rtol=1e-14)
    assert np.all(np.abs(np.sort(Z)[:3]) < np.abs(np.sort(state.Z)[:3]))  # wider along every principal direction
    np.testing.assert_array_equal(M[:, 3], state.M[:, 3])  # the mode kept


@pytest.mark.parametrize("seed", range(10))
def test_mode_and_rms_angle_are_the_binghams(seed):
    """The compiled tick's mode (``w >= 0``) against :attr:`Bingham.mode`, either sign of the mode's column giving
    the same attitude; its RMS angle at the closed forms of the uniform and the point mass."""
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(-2, 9))
    for M in (state.M, state.M * np.array([1.0, 1.0, 1.0, -1.0])):
        q = kernels.mode(np.ascontiguousarray(M))
        assert isinstance(q, tuple) and q[0] >= 0.0
        np.testing.assert_array_equal(q, state.mode)
    assert kernels.rms_angle_deg(np.array([0.25, 0.25, 0.25, 0.25])) == pytest.approx(120.0)  # uniform: 2 asin(sqrt(3/4))
    assert kernels.rms_angle_deg(np.array([0.0, 0.0, 0.0, 1.0])) == 0.0


def _tilt_doubt_deg(state: Bingham) -> float:
    """:func:`tilt_doubt_deg` of a Bingham (it takes ``M`` and the moments: the tick has them from its prediction)."""
    return tilt_doubt_deg(state.M, state.moments("saddlepoint"))


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_down_alignment_and_tilt_variance_match_the_quaternion_forms(seed):
    rng = np.random.default_rng(seed)
    state = random_state(rng, 10.0 ** rng.uniform(-2, 9))
    M = state.M
    along_down = (quat.multiply(np.array([0.0, 0.0, 0.0, 1.0]), M[:, 3]) @ M[:, :3]) ** 2  # k (x) mode against each m_i
    np.testing.assert_allclose(kernels.down_alignment_sq(M), along_down, rtol=1e-13, atol=1e-15)
    moments_ = state.moments()
    variance = float(4.0 * moments_[:3] @ (1.0 - np.minimum(along_down, 1.0)))
    assert _tilt_doubt_deg(state) == pytest.approx(math.degrees(math.sqrt(max(variance, 0.0))), rel=1e-12)


def test_tilt_doubt_counts_the_tilt_axes_only():
    """Closed form at the identity (body axes = world axes, down = body z): E[y_i^2] ~ 1/(2|z_i|), and the tilt
    variance is 4 E[y^2] summed over the axes other than down."""
    heading_spread = Bingham.from_mode(quat.IDENTITY, [-1e9, -1e9, -50.0])  # unsure about the heading only
    tilt_spread = Bingham.from_mode(quat.IDENTITY, [-1e9, -50.0, -1e9])  # unsure about pitch only
    assert _tilt_doubt_deg(heading_spread) == pytest.approx(math.degrees(math.sqrt(4.0 * 2 * 0.5e-9)), rel=0.02)
    assert _tilt_doubt_deg(tilt_spread) == pytest.approx(math.degrees(math.sqrt(4.0 * (0.01 + 0.5e-9))), rel=0.02)


@pytest.mark.parametrize("seed", range(10))
def test_davenport_and_heading_exponents_match_the_numpy_forms(seed):
    rng = np.random.default_rng(seed)
    b, r, sigma = rng.normal(size=3), rng.normal(size=3), 10.0 ** rng.uniform(-3, 0)
    bu, ru = b / np.linalg.norm(b), r / np.linalg.norm(r)
    B = np.outer(ru, bu)  # Davenport's profile matrix, K = [[tr B, z^T], [z, B + B^T - tr(B) I]], z = b x r
    K = np.block([[np.trace(B), np.cross(bu, ru)[None, :]], [np.cross(bu, ru)[:, None], B + B.T - np.trace(B) * np.eye(3)]])
    np.testing.assert_allclose(vector_exponent(b, r, sigma), K / sigma**2, rtol=1e-12, atol=1e-12 / sigma**2)
    q, error = quat.normalize(rng.normal(size=4)), rng.uniform(-math.pi, math.pi)
    v = quat.multiply(np.array([math.sin(0.5 * error), 0.0, 0.0, -math.cos(0.5 * error)]), q)
    np.testing.assert_allclose(heading_exponent(q, error, sigma), (-2.0 / sigma**2) * np.outer(v, v), rtol=1e-13, atol=1e-13 / sigma**2)


@pytest.mark.parametrize("bad", [np.zeros(3), np.array([math.nan, 0.0, 1.0]), np.array([math.inf, 0.0, 0.0]), np.ones(4)])
def test_davenport_refuses_what_is_not_a_direction(bad):
    with pytest.raises(ValueError):
        vector_exponent(bad, np.array([0.0, 0.0, 1.0]), 0.1)


@pytest.mark.parametrize("z", [0.5, 5.0, 50.0, 2_000.0])
def test_rms_angle_is_the_monte_carlo_rms_angle(z):
    """:func:`core.filters.rms_angle_deg` (the compiled kernel on the moments) against the RMS of
    ``sin(theta/2)`` over 200,000 exact draws of the Bingham, ``theta`` each draw's angle to the mode:
    ``sin^2(theta/2) = 1 - (x . mode)^2`` (the draws' standard error is about 0.1 % of the angle). With the exact
    moments within 0.2 %; with the saddlepoint's, which the tick uses, within 1 % (measured: 0.04-0.75 %)."""
    rng = np.random.default_rng(7)
    state = Bingham(random_rotation(rng), np.array([-z, -0.6 * z, -0.2 * z, 0.0]))
    draws = state.sample(200_000, rng)
    mean_sin_sq = float(np.mean(1.0 - (draws @ state.M[:, 3]) ** 2))
    monte_carlo = math.degrees(2.0 * math.asin(math.sqrt(mean_sin_sq)))
    assert rms_angle_deg(state, "exact") == pytest.approx(monte_carlo, rel=0.002)
    assert rms_angle_deg(state) == pytest.approx(monte_carlo, rel=0.01)
