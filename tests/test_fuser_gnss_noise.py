"""A receiver noisier than it claims: the velocity noise its fixes show is measured, and used where it is larger.

The simulated multirotor's first 30 s (hover, then banked turns; tests/test_fuser_gnss_flights.py flies it clean)
with white noise added to every fix's velocity after the simulator made it, while each fix still claims the
simulator's 0.1 m/s (GPS_RAW_INT ``vel_acc``), through the real encoder, decoder and loop; scored against the
simulator's truth. Real receivers do this in multipath, and a message without an accuracy is weighed with
``gnss.velocity_noise_m_s``, a guess.

Measured over eight noise seeds (0-7), RMS after 5 s, reported uncertainty, the truth inside the 90 % region:
0.25 m/s in all under the claim of 0.1, fused as claimed (before :mod:`fuser.model.velocity`'s "Noise"), 2.6-8.1 deg
off reporting 3.4-4.2, inside on 16-92 % of the ticks (one seed of eight within the flight's bound and 85 %); with
the noise measured, six seeds 0.9-1.9 deg at 100 %, two whose first pair restarted the fast start 5.1 (100 %) and
9.3 deg (41 %). 0.5 m/s: before 11-40 deg, 0-38 %; then 6-20 deg, 6-90 %, every seed's first pair restarting the
fast start (the strict xfail below): the first pair is checked before any noise can be measured.

Since every GNSS reading checks the state until it has converged (2026-12-07, :mod:`fuser.model.gravity`), a
restart on a noisy first pair is followed by checks on the next, low-passed pairs, which find the attitude again:
0.25 m/s, all eight seeds 0.9-1.9 deg at 100 % (the two that restart 1.4 and 1.6 deg); 0.5 m/s, 2.1-5.2 deg
reporting 4.6-4.9, the truth inside the 90 % region on 91-100 % of the ticks (measured at d665788 in the same run:
9.3 and 5.1 deg; 6.0-20.5 deg at 6-90 %). Every 0.5-m/s seed still restarts on its first pair. Since the aided
low-pass starts as the running mean of its pairs (:mod:`fuser.model.velocity`, "Sigma"): 0.25 m/s 0.9-1.7 deg, 100 %;
0.5 m/s 1.6-4.7 deg reporting 4.6-5.5, 99-100 %. Since the raw readings' low-pass (``gnss.raw_lowpass_s``) starts as
a running mean too: 0.5 m/s 1.0-3.9 deg, 100 %, seven seeds of eight restarting on their first pair (all eight
before); 0.25 m/s unchanged.

Tried (2026-12-07, stop 34) and not kept: a restart confirmed by a later pair (the first disagreement waiting, the
published tilt covering it, until the next pair's acceleration disagrees too or agrees). At 0.5 m/s two seeds of
eight restarted instead of seven, but the other five were less accurate after 5 s: 1.03-3.90 deg (mean 2.06) ->
1.22-5.23 (mean 2.43), 98-100 % covered; seed 7 2.00 -> 3.34. Without the restart the state kept the tilt its fast
start had converged to, and the aided corrections that followed taught the gyro bias 0.4-0.5 deg/s of x and y in
2-6 s (0-0.1 with the restart, whose recovery the bias does not learn from); holding the bias's learning until the
stream's noise had been measured over 5 or 20 pairs did not change that. The restart is the better start here, so
the strict xfail below stays as the aim it was, not a defect in the figures above.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from test_fuser_gnss_flights import TOTAL_BOUND_DEG, _fly

CLAIMED_M_S = 0.1
"""What every fix claims (the simulator's own noise)."""
ADDED_M_S = 0.23
"""White noise per axis added to each fix: with the simulator's 0.1, 0.25 m/s in all."""
FIVE_TIMES_M_S = 0.49
"""The same, 0.5 m/s in all: five times the claim."""
SEEDS = range(8)


@pytest.fixture(scope="module")
def clean_flight():
    return simulate(SimConfig(seed=0, duration_s=30.0, imu_rate_hz=200.0, gnss_vel_noise_m_s=CLAIMED_M_S))


def _fused(flight, added_m_s: float, seed: int):
    """The flight with ``added_m_s`` of white noise on each fix's velocity (``seed``): (RMS errors, credible levels,
    the velocity noise of each fused pair's diagnostic after 10 s, the loop's counters)."""
    rng = np.random.default_rng(seed)
    vel = flight.gnss.vel_ned_m_s + added_m_s * rng.standard_normal(flight.gnss.vel_ned_m_s.shape)
    noisy = dataclasses.replace(flight, gnss=dataclasses.replace(flight.gnss, vel_ned_m_s=vel))
    noise: list[float] = []

    def watch(loop, estimate):
        if estimate.sensor_t_ns - flight.t_ns[0] > 10e9:
            noise.extend(d["velocity_noise_m_s"] for d in estimate.diagnostics if d["update"] == "velocity" and d["outcome"] == "fused")

    counters: dict = {}
    rms, level = _fly(noisy, FuserConfig(), counters=counters, watch=watch)
    return rms, level, np.array(noise), counters


@pytest.fixture(scope="module")
def five_times(clean_flight):
    """The flight with 0.5 m/s in all, each seed fused once for the tests that read it."""
    return [_fused(clean_flight, FIVE_TIMES_M_S, seed) for seed in SEEDS]


def test_a_receiver_noisier_than_it_claims_is_neither_far_off_nor_overconfident(clean_flight):
    """All eight noise seeds within the flight's RMS bound with the truth inside the 90 % region on 85 % of the ticks
    (before the noise was measured: one; before the restart check ran until convergence: six)."""
    good = []
    for seed in SEEDS:
        rms, level, _, _ = _fused(clean_flight, ADDED_M_S, seed)
        good.append(rms["total"] < TOTAL_BOUND_DEG["multirotor"] and np.mean(level <= 0.9) >= 0.85)
    assert all(good), good


def test_a_receiver_five_times_noisier_than_it_claims_is_not_overconfident(five_times):
    """0.5 m/s under a claim of 0.1: every seed restarts the fast start on its first pair, and the checks after it find
    the attitude again: the truth inside the 90 % region on at least 85 % of the ticks on every seed (measured
    99-100 %, 91-100 % before the aided low-pass started as a running mean; 6-90 % while the first pair alone was
    checked)."""
    coverage = [float(np.mean(level <= 0.9)) for _, level, _, _ in five_times]
    assert min(coverage) >= 0.85, coverage


def test_the_noise_the_fixes_show_is_what_was_added(clean_flight):
    """The measured noise against the noise put in (0.25 m/s per axis in all), not against the filter's own figure."""
    _, _, noise, _ = _fused(clean_flight, ADDED_M_S, 0)
    truth = float(np.hypot(CLAIMED_M_S, ADDED_M_S))
    assert len(noise) > 150
    assert abs(np.median(noise) - truth) < 0.2 * truth, (np.median(noise), truth)


def test_an_honest_receiver_is_weighed_with_about_its_own_figure(clean_flight):
    """The simulator's fixes as they are (0.1 m/s claimed and delivered): the pairs are weighed with about the claim
    (measured 0.108 m/s in the median: the accelerometer's own noise over a pair adds a little), and the flight is as
    accurate as before (1.09 deg)."""
    rms, _, noise, _ = _fused(clean_flight, 0.0, 0)
    assert np.median(noise) == pytest.approx(CLAIMED_M_S, rel=0.15)
    assert np.percentile(noise, 95) < 1.3 * CLAIMED_M_S
    assert rms["total"] < TOTAL_BOUND_DEG["multirotor"], rms


@pytest.mark.xfail(strict=True, reason="the first pair is checked against the state before any noise is measured: at five "
                                       "times its claim seven seeds of eight restart the fast start (the checks after it "
                                       "recover, module docstring)")
def test_a_receiver_five_times_noisier_than_it_claims_does_not_restart_the_fast_start(five_times):
    """Every seed (seed 0 alone no longer restarts since the raw readings' low-pass starts as a running mean)."""
    restarts = [counters.get("gnss_restart", 0) for _, _, _, counters in five_times]
    assert not any(restarts), restarts
