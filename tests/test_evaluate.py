"""Scoring against a reference that arrives out of order, with repeated times or unusable rows: no crash, same errors;
and the credible level of a reference in a Bingham against a brute-force integral over the sphere."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from drivers.scenarios import scenario
from drivers.sim import mavlink_stream
from fuser.cli import main
from fuser.evaluate import REGIONS, attitude_errors, credible_level
from sphere_quadrature import sphere_grid


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Rotation about world down (NED z) by ``yaw``: (cos y/2, 0, 0, sin y/2)."""
    return np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)], axis=-1)


def test_reference_in_receive_order_with_repeats_and_bad_rows() -> None:
    rate = 0.5  # rad/s about down
    ref_t = np.arange(0, 2_000_000_000, 20_000_000, dtype=np.int64)
    ref_q = yaw_quat(rate * ref_t / 1e9)
    est_t = np.arange(100_000_000, 1_900_000_000, 10_000_000, dtype=np.int64)
    offset_deg = 2.0  # every estimate 2 degrees of yaw ahead of the reference
    est_q = yaw_quat(rate * est_t / 1e9 + np.radians(offset_deg))
    unc = np.full(est_t.size, 3.0)

    rng = np.random.default_rng(0)
    order = rng.permutation(ref_t.size)  # receive order, not time order
    t_mixed = np.concatenate([ref_t[order], ref_t[:5], [ref_t[7]]])  # repeated times
    q_mixed = np.concatenate([ref_q[order], ref_q[:5], [[np.nan, 0.0, 0.0, 0.0]]])  # a repeat that is not even finite
    t_mixed = np.concatenate([t_mixed, [ref_t[8] + 1]])
    q_mixed = np.concatenate([q_mixed, [[0.0, 0.0, 0.0, 0.0]]])  # a zero quaternion
    err = attitude_errors(est_t, est_q, unc, t_mixed, q_mixed)
    assert err.t_ns.tolist() == est_t.tolist()
    np.testing.assert_allclose(err.heading_deg, offset_deg, atol=1e-6)
    np.testing.assert_allclose(err.total_deg, offset_deg, atol=1e-6)
    np.testing.assert_allclose(err.tilt_deg, 0.0, atol=1e-6)


def test_fewer_than_two_usable_reference_times_scores_nothing() -> None:
    err = attitude_errors(np.array([1, 2, 3]), yaw_quat(np.zeros(3)), np.ones(3), np.array([5, 5]), yaw_quat(np.zeros(2)))
    assert err.t_ns.size == 0 and err.total_deg.size == 0


def test_replay_of_a_tlog_with_garbage_scores_without_crashing(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The issue's case: garbage between the packets of a .tlog, then scoring against the autopilot's attitude."""
    rng = np.random.default_rng(1)
    tlog = tmp_path / "garbage.tlog"
    with open(tlog, "wb") as f:
        for t_ns, _, data in mavlink_stream(scenario("hover", seed=3)):
            while data:  # one record per MAVLink 2 packet: 10 header bytes, payload, 2 CRC bytes
                size = 12 + data[1]
                f.write(struct.pack(">Q", (t_ns + 1_000_000) // 1000) + data[:size])
                data = data[size:]
            if rng.random() < 0.3:
                f.write(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes())
    assert main(["replay", str(tlog), "-o", str(tmp_path / "out.mcap")]) == 0
    out = capsys.readouterr().out
    assert "error against autopilot attitude" in out or "no estimate within" in out


@pytest.mark.parametrize("z", [(0.0, -100.0, -300.0, -1000.0), (0.0, -400.0, -900.0, -2500.0)])
def test_the_credible_level_is_the_bingham_mass_inside_the_references_contour(z: tuple[float, ...]) -> None:
    """The level of ``q`` is the mass of ``{x: x^T C x > q^T C q}``, here integrated over S^3 with tensor-product
    Gauss-Legendre (tests/sphere_quadrature.py; no chi-square), in the Bingham's principal frame; the level is asked
    of the same Bingham and reference turned by a random rotation of R^4, which must not change it. Concentrations
    of the published estimates (1-6 deg); the quadrature's indicator steps cost about 0.005."""
    Z = np.array(z)
    x, w = sphere_grid(4, 100)
    exponent = Z @ (x * x)
    density = w * np.exp(exponent)
    rng = np.random.default_rng(7)
    M, _ = np.linalg.qr(rng.standard_normal((4, 4)))  # columns: the principal directions, the first the mode
    for scale in (0.3, 0.7, 1.0, 1.5, 2.5):
        y = np.concatenate(([1.0], scale * rng.standard_normal(3) / np.sqrt(-2.0 * Z[1:])))
        y /= np.linalg.norm(y)  # the reference in the principal frame: about `scale` sigmas from the mode
        integral = density[exponent > Z @ (y * y)].sum() / density.sum()
        level = credible_level(M[None], Z[None], (M @ y)[None])[0]
        assert abs(level - integral) < 0.02, (scale, level, integral)


def test_coverage_counts_the_estimates_whose_region_holds_the_reference() -> None:
    """Estimates whose reference lies at a known level (isotropic Binghams, the reference turned by a chosen angle
    about down): the coverage of each region is the share of those levels at most its mass, after ``since_s``."""
    z = -500.0
    t = np.arange(10, dtype=np.int64) * 1_000_000_000
    angle = np.array([0.02, 0.05, 0.08, 0.10, 0.12, 0.15, 0.2, 0.25, 0.3, 0.4])  # radians
    levels = chi2_cdf_isotropic(z, angle)
    est_q = yaw_quat(np.zeros(t.size))
    bingham = np.repeat(np.eye(4)[None], t.size, axis=0), np.repeat(np.array([[0.0, z, z, z]]), t.size, axis=0)
    err = attitude_errors(t, est_q, np.ones(t.size), t, yaw_quat(angle), bingham)
    np.testing.assert_allclose(err.level, levels, atol=1e-9)
    for since_s in (0.0, 3.5):
        later = t >= since_s * 1e9
        assert err.coverage(since_s) == {a: float(np.mean(levels[later] <= a)) for a in REGIONS}
    assert attitude_errors(t, est_q, np.ones(t.size), t, yaw_quat(angle)).coverage() == {}  # no Binghams, no coverage


def chi2_cdf_isotropic(z: float, angle: np.ndarray) -> np.ndarray:
    """The level of a reference ``angle`` away from the mode of an isotropic Bingham ``(0, z, z, z)``: ``x^T C x`` is
    ``z sin^2(angle / 2)``, and ``-2 x^T C x`` chi-square with 3 degrees of freedom (scipy)."""
    from scipy.stats import chi2

    return chi2.cdf(-2.0 * z * np.sin(angle / 2) ** 2, 3)
