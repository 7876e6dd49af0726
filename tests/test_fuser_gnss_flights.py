"""The simulated flights with GNSS aiding, through the real encoders, decoders and loop: RMS error bounds against
the simulator's truth, what the aiding buys, and whether the reported uncertainty covers the truth.

Short versions of the README's flights (200 Hz IMU, GNSS as GPS_RAW_INT at 10 Hz, 0.15 s old, as ``bingham-fuser
sim`` sends them): the multirotor's first 30 s (hover, banked turns, the start of the aggressive manoeuvres), the
aggressive scenario (28 s, up to 500 deg/s), and the JSBSim Cessna's first 60 s (level, then a sustained
coordinated 30-deg turn). RMS after the first 5 s. The bounds are the issue's (multirotor total 3 deg,
aggressive 4 deg, fixed wing tilt 2 and total 3 deg); measured on these seeds: 0.7, 1.3, 1.0 / 2.3 deg.

Coverage: the truth inside the 90 % credible region (:func:`fuser.evaluate.credible_level`) on 85-95 % of the
ticks. It is at least 85 %: the published uncertainty is not overconfident with aiding (without it, 30-74 %: the unseen turn, below).
It is above 95 % on these flights (100 %): the published heading uncertainty keeps the model error's 3.25-deg
floor and the magnetometer's 2-deg correlated error, both fitted on BROAD's distorted fields, while the
simulator's magnetometer reads the field exactly, and the tilt's keeps the gyro bias floor's process noise.
Those are the ``accuracy`` branch's (``fuser/model_error.py``, ``fuser/model/heading.py``, ``bias.py``); the
upper bound is a strict xfail until they change.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.scenarios import scenario
from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from fuser.evaluate import attitude_errors, credible_level
from fuser.inputs import sim_ticks
from fuser.loop import FusionLoop

jsbsim = pytest.importorskip("jsbsim")
from drivers import jsbsim_flight  # noqa: E402

FLIGHTS = {
    "multirotor": lambda: simulate(SimConfig(seed=0, duration_s=30.0, imu_rate_hz=200.0)),
    "aggressive": lambda: scenario("aggressive", seed=0, imu_rate_hz=200.0),
    "fixedwing": lambda: jsbsim_flight.simulate_fixed_wing(jsbsim_flight.fixed_wing_config(seed=0, imu_rate_hz=200.0, duration_s=60.0)),
}
TOTAL_BOUND_DEG = {"multirotor": 3.0, "aggressive": 4.0, "fixedwing": 3.0}
TILT_BOUND_DEG = {"fixedwing": 2.0}


def _fly(flight, config: FuserConfig):
    """The flight's MAVLink bytes through the decoder and the loop, received 1 ms after sending; the errors after
    5 s and the credible level of the truth at each of those estimates."""
    loop = FusionLoop(config)
    estimates = []
    for t, _, samples in sim_ticks(flight):
        estimates += loop.advance(t + 1_000_000)
        for s in samples:
            loop.push(s, t + 1_000_000)
    estimates += loop.flush()
    est = [e for e in estimates if e.sensor_t_ns is not None]
    err = attitude_errors(np.array([e.sensor_t_ns for e in est]), np.array([e.q_wxyz for e in est]),
                          np.array([e.uncertainty_deg for e in est]), flight.t_ns, flight.q_true)
    inside = np.isin(np.array([e.sensor_t_ns for e in est]), err.t_ns)
    after = (err.t_ns - err.t_ns[0]) >= 5e9
    M = np.array([e.M for e in est])[inside][after]
    Z = np.array([e.Z for e in est])[inside][after]
    return err.rms(5.0), credible_level(M, Z, err.q_ref[after])


@pytest.fixture(scope="module", params=sorted(FLIGHTS))
def flown(request):
    flight = FLIGHTS[request.param]()
    return request.param, _fly(flight, FuserConfig()), _fly(flight, FuserConfig().replace(gnss={"enabled": False}))


def test_aided_flights_meet_their_rms_bounds(flown):
    name, (rms, _), _ = flown
    assert rms["total"] < TOTAL_BOUND_DEG[name], rms
    assert rms["tilt"] < TILT_BOUND_DEG.get(name, np.inf), rms


def test_without_gnss_the_same_flights_miss_them(flown):
    """What the aiding buys: the accelerometer alone takes the thrust or the lift for gravity in the turns, at least
    twice as far off (the multirotor's 30 s alone: 2.7 deg total, 2.3 tilt, against 0.85 and 0.48 aided; before the
    bias was learnt in motion without GNSS it also missed the 3-deg bound)."""
    name, (aided, _), (alone, _) = flown
    assert alone["total"] > 2.0 * aided["total"] and alone["tilt"] > 2.0 * aided["tilt"], (aided, alone)


def test_with_aiding_the_reported_uncertainty_is_not_overconfident(flown):
    _, (_, level), _ = flown
    assert np.mean(level <= 0.9) >= 0.85, np.mean(level <= 0.9)


def test_without_gnss_the_unseen_turn_widens_the_uncertainty(flown):
    """Without GNSS the accelerometer takes the fixed wing's lift in a sustained turn for gravity and nothing in the
    innovations shows it; the low-passed specific force's excess norm does (fuser/model/unaided.py), and the published
    Bingham widens. Measured, seed 0: the 90 % region holds the truth on 74 % of the ticks, 19.1 deg RMS off reporting
    42.8 (before the widening: 21 %, reporting 11.4). Not met for the multirotor (57 %, 4.35 deg off reporting 5.1;
    aggressive: 30 %, 6.2 off reporting 4.2): its tilt error builds in manoeuvres whose low-passed excess norm stays
    within the accelerometer's tolerance (``accel.unaided_norm_tolerance_fraction``, 3 %)."""
    name, _, (alone, level_alone) = flown
    if name != "fixedwing":
        pytest.xfail(f"{name} without GNSS: under-covered (docstring)")
    assert np.mean(level_alone <= 0.9) >= 0.7, np.mean(level_alone <= 0.9)
    assert alone["uncertainty"] >= alone["total"], alone


@pytest.mark.xfail(strict=True, reason="over-covered (100 %): the heading floor and the bias floor are fitted on BROAD's "
                                       "distorted fields and sensors, the simulator's are exact (module docstring)")
def test_with_aiding_the_reported_uncertainty_is_calibrated(flown):
    _, (_, level), _ = flown
    assert np.mean(level <= 0.9) <= 0.95, np.mean(level <= 0.9)
