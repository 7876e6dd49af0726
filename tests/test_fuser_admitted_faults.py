"""Faults the filter cannot see coming are detected, counted, kept out, admitted in the published uncertainty,
and the estimate recovers (tests/fault_flights.py builds the flights; the truth is the simulator's).

Before these were handled (commit 14a9397, the same flights): 2 s of a saturated gyro left the estimate
176 deg off while it reported 7 deg; a rogue second IMU 64 deg off reporting 6 deg, not recovered 4 s
after; a 30-deg jump of the autopilot's attitude was followed, 30 deg off reporting 6 deg. Before frozen axes were
kept out (ae42f20): a second IMU whose x gyro stuck at 0.5 rad/s was averaged in, 36 deg off reporting 3.8-14,
not recovered by 12 s, nothing counted.
"""

from __future__ import annotations

import numpy as np
import pytest

from fault_flights import FAULTS, RECOVERED_DEG, bias_step, saturation

COUNTER = {"saturation": "gyro_saturated", "rogue_imu": "imu_disagree", "stuck_imu": "imu_disagree", "attitude_jump": "attitude_gated_jump",
           "saturation_in_turn": "gyro_saturated"}
EXPECTED_COUNT = {"saturation": 2.0 * 200 * 0.95, "rogue_imu": 4.0 * 200 * 0.95, "stuck_imu": 4.0 * 200 * 0.9, "attitude_jump": 4.0 * 3.5 * 0.7,
                  "saturation_in_turn": 2.0 * 200 * 0.95}
"""At least this many faulty readings are counted: 2 s of the 200 Hz gyro, 4 s of the 200 Hz rogue IMU, 4 s of the
stuck one less the ``frozen_samples`` (50) it takes to call it frozen, most of 4 s of the 3.5 Hz attitude (some arrive while the estimate still agrees with them)."""


@pytest.fixture(scope="module", params=sorted(FAULTS))
def run(request):
    return request.param, FAULTS[request.param]()


def test_the_fault_is_detected_and_counted(run):
    name, r = run
    assert r.counters.get(COUNTER[name], 0) >= EXPECTED_COUNT[name], r.counters


def test_while_it_lasts_the_published_uncertainty_covers_the_error_and_grows(run):
    _, r = run
    during = r.window(r.start_s, r.end_s)
    before = r.window(r.start_s - 2.0, r.start_s)
    assert np.all(r.error_deg[during] < 2.0 * r.uncertainty_deg[during]), (r.error_deg[during].max(), r.uncertainty_deg[during].min())
    assert r.uncertainty_deg[during].mean() > r.uncertainty_deg[before].mean() + 0.5


@pytest.mark.parametrize("name", ["rogue_imu", "attitude_jump"])
def test_a_faulty_source_with_a_healthy_peer_is_kept_out_of_the_state(name):
    r = FAULTS[name]()
    assert r.error_deg[r.window(r.start_s, r.end_s)].max() < RECOVERED_DEG


def test_a_frozen_gyro_axis_is_averaged_in_only_until_it_counts_as_frozen():
    """The second IMU's x gyro stuck at 0.5 rad/s passes the per-sample comparison with the first's (within
    ``disagree_rad_s``) and, being the smoother, would win the pair; it is kept out once it has repeated its value
    ``frozen_samples`` (50) times, 0.25 s at 200 Hz, in which the average, off by up to half of 0.5 rad/s, turns the
    estimate by at most 3.6 deg more than it was off before (measured: 5.4 deg at most; 36 deg, never recovered,
    before frozen axes were kept out)."""
    r = FAULTS["stuck_imu"]()
    before = r.error_deg[r.window(r.start_s - 2.0, r.start_s)].max()
    assert r.error_deg[r.window(r.start_s, r.end_s)].max() < before + np.degrees(0.25 * 0.25) + 1.0


def test_the_estimate_recovers_within_5_s_of_the_fault_ending(run):
    """Also in a sustained banked turn, where it takes the GNSS velocity: the accelerometer alone re-converges
    to the bank's false vertical (7.4 s to never, seeds 0-3; 3.6-4.2 s with GNSS)."""
    _, r = run
    assert r.recovery_s <= 5.0, r.summary()


def test_after_it_the_published_uncertainty_still_covers_the_error(run):
    """After the fault the error stays within twice the reported uncertainty. In the banked turn (seed 0) the
    restarted gravity update's raw readings point 15 deg off and the first GNSS-aided readings need 3 s to pull
    the estimate back: before the unseen tilt was kept through them (fuser/model/unaided.py) the estimate was
    15 deg off reporting 5 for 2.6 s (seeds 0-3, with and without GNSS: benchmarks/faults.py)."""
    _, r = run
    after = r.window(r.end_s, r.scored_until_s)
    assert np.all(r.error_deg[after] <= 2.0 * r.uncertainty_deg[after]), r.summary()


def test_the_recovery_from_a_saturated_gyro_teaches_the_bias_nothing():
    """Seed 3's hover (its gyro bias 1.5 deg/s, not yet learnt when the gyro saturates): the corrections while
    the attitude re-converges are the recovery's, not the bias's. Learnt from, they took the z bias 1.4 deg/s off
    within 2 s and the estimate drifted 9 deg off reporting 4 (2.95 s above twice the reported uncertainty)."""
    r = saturation(seed=3)
    after = r.window(r.end_s, r.scored_until_s)
    assert np.all(r.error_deg[after] <= 2.0 * r.uncertainty_deg[after]), r.summary()


def test_a_gyro_bias_appearing_in_flight_without_gnss_widens_while_gravity_is_kept_out():
    """The same bias without GNSS: the accelerometer's tilt, kept out by the innovation gate as the state drifts
    away, disputes the state, and the published tilt covers the reading kept out (fuser/model/gravity.py). Before
    (ae42f20) the estimate was over twice its reported uncertainty on 32.8 % of the estimates from 4 to 30 s (25 deg
    off reporting 6); now 14.9 %: what is left is the drift's start, which the strapdown low-pass hides from the
    innovation (its frame drifts with the bias), and the heading after the tilt has come back. The accuracy is
    unchanged: the accelerometer alone cannot tell a bias from a turn's false vertical (fuser/model/unaided.py)."""
    r = bias_step(gnss=False)
    during = r.window(r.start_s, r.end_s)
    assert r.counters.get("accel_gated_innovation", 0) > 0
    assert np.mean(r.error_deg[during] > 2.0 * r.uncertainty_deg[during]) < 0.2


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_a_gyro_bias_appearing_in_flight_with_gnss_is_shown_by_the_fixes(seed):
    """The same bias with GNSS: the aided readings, low-passed in the frame the biased gyro turns, drift along with
    the state and keep agreeing with it (7-11 deg off, every innovation 1-3 deg against a sigma of 4); each pair of
    fixes' residual against the state shows the error, and the published attitude covers it
    (fuser/model/velocity_check.py). Over twice the reported uncertainty from 4 to 30 s: 43.6 / 39.0 / 37.6 /
    54.7 % of the estimates before (seeds 0-3, c50e74e); with the check 0.5 / 0 / 0 / 12.2 % (seed 3's from its
    start, 9-10 deg off reporting 4 before the step, its 1.5 deg/s bias unlearnt); with the aided low-pass started
    as a running mean too, 0 % on all four. The accuracy is about the same (6.8-9.1 deg RMS): the state is not
    corrected by the check."""
    r = bias_step(seed=seed)
    during = r.window(r.start_s, r.end_s)
    assert r.counters.get("gnss_disputes", 0) > 0
    assert np.mean(r.error_deg[during] > 2.0 * r.uncertainty_deg[during]) < 0.05
