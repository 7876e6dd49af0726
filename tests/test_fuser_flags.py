"""A matrix over the model's feature flags: every combination flies the same short simulated flight and stays
accurate against the simulator's truth (VQF's tests run the same kind of matrix over its booleans).

The flight: 2 s at rest (so that rest detection has something to detect), then the simulator's hover with
small attitude changes, at 200 Hz with the simulator's noise and bias, and a second IMU of the vehicle (its
own bias and noise, so that the IMU cross-check has something to check), through the real loop. Errors are
scored against the simulator's true attitude after 3 s of convergence. Without a magnetometer and without
the autopilot's attitude the heading is unobservable (the state starts uniform), so only the tilt is scored.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import AttitudeSample, ImuSample
from drivers.sim import GRAVITY_M_S2, SIM_SOURCE, SimConfig, samples, simulate
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

REST_S = 2.0
SIM = SimConfig(seed=1, duration_s=4.0, imu_rate_hz=200.0)
TILT_BOUND_DEG = 2.5
"""RMS tilt after convergence; measured 1.1-1.8 deg (worst without any bias estimation)."""
TOTAL_BOUND_DEG = 3.0
"""RMS total error when the heading is observable (magnetometer or attitude); measured 2.2-2.4 deg with the
magnetometer alone."""
AIDED_BOUND_DEG = 1.0
"""RMS total error when the autopilot's attitude (0.57 deg per axis, 25 Hz) is fused; measured 0.2-0.4 deg."""


def _flight_with_rest():
    """(time ns, true q, samples) per IMU sample: ``REST_S`` seconds still at the flight's first attitude, then the flight
    (with its GNSS fixes at 10 Hz, so that the first fix gives the WMM field mid-way and GNSS aiding can run)."""
    flight = simulate(SIM)
    rng = np.random.default_rng(5)
    period_ns = round(1e9 / SIM.imu_rate_hz)
    n = round(REST_S * SIM.imu_rate_hz)
    q0 = flight.q_true[0]
    f0 = quat.rotate(quat.conjugate(q0), [0.0, 0.0, -GRAVITY_M_S2]) + flight.accel_bias_m_s2[0]
    m0 = quat.rotate(quat.conjugate(q0), np.asarray(flight.mag_field_ned_gauss))
    t_start = int(flight.t_ns[0])
    out = []
    for k in range(n):
        gyro = flight.gyro_bias_rad_s[0] + SIM.gyro_noise_rad_s * rng.standard_normal(3)
        accel = f0 + SIM.accel_noise_m_s2 * rng.standard_normal(3)
        mag = tuple(m0 + SIM.mag_noise_gauss * rng.standard_normal(3)) if k % 2 == 0 else None
        t = t_start + k * period_ns
        out.append((t, q0, [ImuSample(t, tuple(gyro), tuple(accel), mag, SIM_SOURCE)]))
    shift = n * period_ns
    second = dataclasses.replace(SIM_SOURCE, instance=1)
    bias = 0.005 * rng.standard_normal(3)
    for k, (t, q, ss) in enumerate(samples(flight)):
        out.append((t + shift, q, [dataclasses.replace(s, t_ns=s.t_ns + shift) for s in ss]))
        gyro = flight.gyro_true_rad_s[k] + bias + SIM.gyro_noise_rad_s * rng.standard_normal(3)
        accel = flight.accel_true_m_s2[k] + SIM.accel_noise_m_s2 * rng.standard_normal(3)
        out.append((t + shift + 1_000_000, q, [ImuSample(t + shift + 1_000_000, tuple(gyro), tuple(accel), None, second)]))
    return out


FLIGHT = _flight_with_rest()
FLAGS = list(itertools.product([True, False], [True, False], [True, False], [True, False], ["off", "always", "auto"], [True, False]))


def _errors(config: FuserConfig) -> tuple[np.ndarray, np.ndarray, dict]:
    """Total and tilt error (deg) of every estimate after 3 s, against the truth at the estimate's sensor time,
    and the model's counters."""
    loop = FusionLoop(config)
    estimates = []
    for t, _, ss in FLIGHT:
        estimates += loop.advance(t + 1_000_000)
        for s in ss:
            loop.push(s, t + 1_000_000)
    estimates += loop.flush()
    t_true = np.array([t for t, _, _ in FLIGHT])
    q_true = np.array([q for _, q, _ in FLIGHT])
    est = [e for e in estimates if t_true[0] + 3e9 <= e.sensor_t_ns <= t_true[-1]]
    truth = q_true[np.searchsorted(t_true, [e.sensor_t_ns for e in est])]
    q = np.array([e.q_wxyz for e in est])
    total = np.degrees(quat.angular_distance(q, truth))
    down = np.array([0.0, 0.0, 1.0])  # world down seen in the body: independent of the heading
    tilt = np.degrees(np.arccos(np.clip(np.sum(quat.rotate(quat.conjugate(q), down) * quat.rotate(quat.conjugate(truth), down), axis=1), -1, 1)))
    return total, tilt, dict(loop.model.counters)


@pytest.mark.parametrize("mag, feedback, rest, imu_check, attitude, gnss", FLAGS, ids=lambda v: str(v))
def test_every_flag_combination_stays_accurate(mag, feedback, rest, imu_check, attitude, gnss):
    config = FuserConfig().replace(mag={"enabled": mag}, bias={"feedback_enabled": feedback}, rest={"enabled": rest},
                                   imu_check={"enabled": imu_check}, attitude={"mode": attitude}, gnss={"enabled": gnss})
    total, tilt, counters = _errors(config)
    assert (counters.get("gnss_fused", 0) > 30) == gnss, counters  # 10 Hz fixes over the 4-s flight, once converged
    rms = lambda v: float(np.sqrt(np.mean(v**2)))  # noqa: E731
    assert rms(tilt) < TILT_BOUND_DEG, rms(tilt)
    if attitude == "always":
        assert rms(total) < AIDED_BOUND_DEG, rms(total)
    if attitude != "always":  # two 200 Hz IMUs: "auto" does not fuse the attitude either
        assert counters["attitude_unused"] == sum(isinstance(s, AttitudeSample) for _, _, ss in FLIGHT for s in ss), counters
    elif mag:
        assert rms(total) < TOTAL_BOUND_DEG, rms(total)


def test_the_flight_holds_what_the_flags_switch():
    """The matrix means something only if the flight exercises each feature: rest is detected, attitude
    samples arrive, and the magnetometer is read."""
    loop = FusionLoop(FuserConfig().replace(attitude={"mode": "always"}))
    for t, _, ss in FLIGHT:
        loop.advance(t + 1_000_000)
        for s in ss:
            loop.push(s, t + 1_000_000)
    loop.flush()
    assert loop.model.counters["rest_ticks"] > 20
    assert np.count_nonzero(loop.model.state.imu_check.seen) == 2 and loop.model.counters["imu_disagree"] == 0  # both IMUs seen
    assert any(isinstance(s, AttitudeSample) for _, _, ss in FLIGHT for s in ss)
    assert any(d["update"] == "heading" for d in loop.diagnostics().values())
