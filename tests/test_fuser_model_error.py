"""The published model error (fuser/model_error.py): floors plus a term proportional to the recent rotation rate."""

import math

import numpy as np

from core import quaternion as quat
from core.bingham import Bingham
from drivers.samples import ImuSample
from fuser.config import FuserConfig, ModelErrorSettings
from fuser.model import FusionModel
from fuser.model_error import model_error_variances, observe_rate, widened_concentrations, with_model_error
from fusion_inputs import FIELD, GRAVITY_M_S2, SRC, TICK, tick
from model_records import params, part


def spin(model: FusionModel, rate_rad_s: float, seconds: float) -> list:
    """A level sensor turning about world down at ``rate_rad_s``: 4 IMU samples per tick, noise-free."""
    out = []
    for k in range(round(seconds * 100)):
        samples = []
        for j in range(1, 5):
            t_ns = k * TICK + j * 2_500_000
            q = quat.from_rotvec([0.0, 0.0, rate_rad_s * t_ns * 1e-9])
            f = quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2])
            m = quat.rotate(quat.conjugate(q), FIELD)
            samples.append(ImuSample(t_ns, (0.0, 0.0, rate_rad_s), tuple(f), tuple(m), SRC))
        out.append(model.step(tick(samples, (k + 1) * TICK)))
    return out


def test_rate_term_settles_to_the_configured_time_times_the_rate():
    settings = params(FuserConfig(model_error=ModelErrorSettings(tilt_deg=0.5, heading_deg=1.0, rate_s=0.004))).model_error
    me = part("model_error")  # the state's model_error part, changed in place by observe_rate
    assert model_error_variances(settings, me.rate_sq, True) == (math.radians(0.5) ** 2, math.radians(1.0) ** 2)  # at rest: the floors
    for _ in range(3000):  # 30 s = 10 low-pass time constants of 3 s at 5 rad/s
        observe_rate(me, 5.0, 0.01, 3.0)
    tilt, heading = model_error_variances(settings, me.rate_sq, True)
    assert math.isclose(tilt, math.radians(0.5) ** 2 + (0.004 * 5.0) ** 2, rel_tol=1e-3)
    assert math.isclose(heading - tilt, math.radians(1.0) ** 2 - math.radians(0.5) ** 2, rel_tol=1e-9)
    observe_rate(me, 1.0, 0.0, 3.0)  # a zero-length tick changes nothing and makes no NaN
    assert model_error_variances(settings, me.rate_sq, True) == (tilt, heading)


def test_heading_floor_needs_a_magnetometer():
    settings = params(FuserConfig(model_error=ModelErrorSettings(heading_deg=2.0, tilt_deg=0.0))).model_error
    assert model_error_variances(settings, 0.0, heading_floor=False) == (0.0, 0.0)


def test_published_uncertainty_grows_with_the_rotation_rate_and_the_estimate_is_unchanged():
    cfg = FuserConfig(model_error=ModelErrorSettings(rate_s=0.004))
    fast = spin(FusionModel(cfg), math.radians(400.0), 8.0)
    flat = spin(FusionModel(cfg.replace(model_error={"rate_s": 0.0})), math.radians(400.0), 8.0)
    slow = spin(FusionModel(cfg), math.radians(20.0), 8.0)
    # 4 ms at 400 deg/s is 1.6 deg per axis once the 3-s low-pass has settled: on three axes it adds
    # 3 * 1.6^2 deg^2 to the squared RMS angle
    added = fast[-1].uncertainty_deg ** 2 - flat[-1].uncertainty_deg ** 2
    assert 0.7 < added / (3 * math.degrees(0.004 * math.radians(400.0)) ** 2) < 1.3
    assert fast[-1].uncertainty_deg > slow[-1].uncertainty_deg + 0.5
    assert quat.angular_distance(fast[-1].q_wxyz, flat[-1].q_wxyz) < 1e-9  # published-only: the filter is untouched
    assert all(np.isfinite(e.uncertainty_deg) for e in fast)


def test_stacked_widening_matches_one_state_at_a_time():
    """``widened_concentrations`` on a stack (as benchmarks/fit_model_error.py scores) is the per-tick path."""
    rng = np.random.default_rng(5)
    states = [Bingham.from_mode(quat.from_rotvec(rng.normal(size=3)), -np.sort(rng.uniform(1.0, 1e5, 3))[::-1]) for _ in range(6)]
    tilt, heading = rng.uniform(0.0, 1e-3, 6), rng.uniform(0.0, 1e-2, 6)
    stacked = widened_concentrations(np.array([b.M for b in states]), np.array([b.Z for b in states]), tilt[:, None], heading[:, None])
    for k, b in enumerate(states):
        expected_M, expected_Z = with_model_error(b.M, b.Z, tilt[k], heading[k])
        exponent = b.M @ np.diag(np.r_[stacked[k], 0.0]) @ b.M.T  # same principal directions, widened
        np.testing.assert_allclose(exponent, expected_M @ np.diag(expected_Z) @ expected_M.T, rtol=1e-10, atol=1e-9)
