"""The simulated flights with GNSS aiding, through the real encoders, decoders and loop: RMS error bounds against
the simulator's truth, what the aiding buys, and whether the reported uncertainty covers the truth.

Short versions of the README's flights (200 Hz IMU, GNSS as GPS_RAW_INT at 10 Hz, 0.15 s old, as ``bingham-fuser
sim`` sends them): the multirotor's first 30 s (hover, banked turns, the start of the aggressive manoeuvres), the
aggressive scenario (28 s, up to 500 deg/s), and the JSBSim Cessna's first 60 s (level, then a sustained
coordinated 30-deg turn). RMS after the first 5 s. The bounds are the issue's (multirotor total 3 deg,
aggressive 4 deg, fixed wing tilt 2 and total 3 deg); measured on these seeds (2026-12-07, stop 34): 0.92, 1.37,
0.73 / 0.89 deg.

Coverage: the truth inside the 90 % credible region (:func:`fuser.evaluate.credible_level`) on 85-95 % of the
ticks. It is at least 85 %: the published uncertainty is not overconfident, with aiding or without it (below).
It is above 95 % on these flights (100 %): the published heading uncertainty keeps the model error's 2.5-deg
floor and the magnetometer's 2-deg correlated error, both fitted on BROAD's distorted fields, while the
simulator's magnetometer reads the field exactly, and the tilt's keeps the gyro bias floor's process noise
(``fuser/model_error.py``, ``fuser/model/heading.py``, ``bias.py``). Measured (2026-12-07): reporting 3.34 /
3.56 / 3.03 deg for 0.92 / 1.37 / 0.89 deg off; with the 0.5-deg floor BROAD's out-of-sample fits choose, 2.29 /
2.59 / 1.81, still 100 %; with the magnetometer's error at 0.5 deg too, the multirotor 1.81 for 0.83 (100 %) and
the Cessna 3.44 deg off at 68 % (README, "Simulated flights"). The upper bound is a strict xfail: defaults fitted
to the simulator's exact sensors would be overconfident on real ones.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.samples import GnssSample
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
    "fixedwing": functools.cache(lambda: jsbsim_flight.simulate_fixed_wing(jsbsim_flight.fixed_wing_config(seed=0, imu_rate_hz=200.0,
                                                                                                         duration_s=60.0))),
}
TOTAL_BOUND_DEG = {"multirotor": 3.0, "aggressive": 4.0, "fixedwing": 3.0}
TILT_BOUND_DEG = {"fixedwing": 2.0}


def received(flight) -> Iterator[tuple[int, list]]:
    """The flight's MAVLink bytes through the decoder: (receive time, samples), received 1 ms after sending."""
    for t, _, samples in sim_ticks(flight):
        yield t + 1_000_000, samples


def _fly(flight, config: FuserConfig, after_s: float = 5.0, counters: dict | None = None, watch=None, deliveries=None):
    """The flight's samples (``deliveries``, :func:`received` by default) through the loop; the errors after
    ``after_s`` and the credible level of the truth at each of those estimates, the ticks' and the output
    predictor's (the loop's counters into ``counters``; ``watch(loop, estimate)`` called for each tick's estimate as
    the advance that made it returns)."""
    loop = FusionLoop(config)
    estimates = []
    for receive_ns, samples in received(flight) if deliveries is None else deliveries:
        for e in loop.advance(receive_ns):
            estimates.append(e)
            if watch is not None:
                watch(loop, e)
        for s in samples:
            estimates += loop.push(s, receive_ns)  # between ticks, the output predictor's at every IMU sample
    estimates += loop.flush()
    est = [e for e in estimates if e.sensor_t_ns is not None]
    err = attitude_errors(np.array([e.sensor_t_ns for e in est]), np.array([e.q_wxyz for e in est]),
                          np.array([e.uncertainty_deg for e in est]), flight.t_ns, flight.q_true)
    inside = np.isin(np.array([e.sensor_t_ns for e in est]), err.t_ns)
    after = (err.t_ns - err.t_ns[0]) >= after_s * 1e9
    M = np.array([e.M for e in est])[inside][after]
    Z = np.array([e.Z for e in est])[inside][after]
    if counters is not None:
        counters.update(loop.counters | loop.model.counters)
    return err.rms(after_s) | {"max": float(err.total_deg[after].max())}, credible_level(M, Z, err.q_ref[after])


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
    twice as far off (the multirotor's 30 s alone: 2.4 deg total, 2.1 tilt, against 1.09 and 0.66 aided; before the
    bias was learnt in motion without GNSS it also missed the 3-deg bound)."""
    name, (aided, _), (alone, _) = flown
    assert alone["total"] > 2.0 * aided["total"] and alone["tilt"] > 2.0 * aided["tilt"], (aided, alone)


def test_with_aiding_the_reported_uncertainty_is_not_overconfident(flown):
    _, (_, level), _ = flown
    assert np.mean(level <= 0.9) >= 0.85, np.mean(level <= 0.9)


def test_without_gnss_the_unseen_acceleration_widens_the_uncertainty(flown):
    """Without GNSS the accelerometer takes the fixed wing's lift in a sustained turn, and the multirotor's thrust in
    its manoeuvres, for gravity, and its innovations do not show it. Two accounts widen the published Bingham
    (fuser/model/unaided.py): the low-passed specific force's excess norm (a sustained turn), and the tilt the
    plain update's corrections have absorbed (a transient: a multirotor's thrust norm grows only with the square of
    its acceleration, so its 2-5 deg errors stay within the norm's tolerance). Measured, seed 0, 90 % region
    (RMS off, reported): multirotor 97 % (2.4 deg, 4.0), aggressive 96 % (3.4, 4.5), fixed wing 90 % (11.1, 50.1).
    Before the absorbed tilt: 48 % (2.9, 3.6), 33 % (4.3, 3.8), 75 % (12.9, 50.4); before the excess norm the fixed
    wing was at 21 %, reporting 11.4."""
    name, _, (alone, level_alone) = flown
    coverage = float(np.mean(level_alone <= 0.9))
    assert coverage >= 0.85 and alone["uncertainty"] >= alone["total"], (name, coverage, alone)


def test_in_a_sustained_turn_without_gnss_the_bias_does_not_learn_the_false_vertical():
    """The JSBSim Cessna's 30-deg turn without GNSS at a 200 Hz loop (no rest found in the cruise before it): the
    tilt corrections of the turn's entry all point one way in the body, as a bias's would. Counted in the bias's
    tilt evidence noise by what they absorbed (fuser/model/bias.py, :func:`fuser.model.unaided.absorbed`), they no
    longer teach it the turn: the learnt bias stays within 0.7 deg/s of the simulator's on every axis (before: 2.0
    deg/s about the roll axis, the estimate then 41 deg off in a 30-deg bank). And the accelerometer is gated in
    the turn as at 100 Hz (fuser/model/gravity.py: the gate against the low-passed down's own error, not the
    gain-setting sigma, which grows with the loop rate): 9.4 deg RMS tilt after 5 s, 14.7 total (before either,
    68 total; with the bias kept, 24.8 tilt and 48 total)."""
    flight = FLIGHTS["fixedwing"]()
    worst, counters = np.zeros(3), {}

    def bias_error(loop, e):
        if (e.t_ns - flight.t_ns[0]) * 1e-9 > 10.0:  # after the bias's first convergence
            i = min(int(np.searchsorted(flight.t_ns, e.t_ns)), len(flight.t_ns) - 1)
            np.maximum(worst, np.abs(np.degrees(loop.model.state.bias.estimate_rad_s - flight.gyro_bias_rad_s[i])), out=worst)

    rms, _ = _fly(flight, FuserConfig().replace(rate_hz=200.0, gnss={"enabled": False}), counters=counters, watch=bias_error)
    assert counters.get("rest_ticks", 0) == 0
    assert np.all(worst < 1.0), worst
    assert rms["tilt"] < 15.0 and rms["total"] < 25.0, rms


@pytest.mark.xfail(strict=True, reason="over-covered (100 %): the heading floor and the bias floor are fitted on BROAD's "
                                       "distorted fields and sensors, the simulator's are exact (module docstring)")
def test_with_aiding_the_reported_uncertainty_is_calibrated(flown):
    _, (_, level), _ = flown
    assert np.mean(level <= 0.9) <= 0.95, np.mean(level <= 0.9)


@pytest.mark.parametrize("start_s", [22.0, 25.0, 28.0, 31.0, 34.0, 40.0])
def test_a_start_in_a_sustained_turn_finds_the_attitude(start_s):
    """Started in the JSBSim flight's sustained 30-deg turn (15-55 s; a ground station connecting mid-flight): the
    first raw readings are the lift's direction, the bank's vertical. The GNSS fixes show it (a raw reading with the
    turn's acceleration taken out disagrees beyond the gate, at the first pair or one of the next before the state
    converges), the fast start runs again with the acceleration taken out and the whole field as a vector, and the
    field stays a vector until the aided correction has settled (fuser/model/gravity.py, heading.py). Measured
    (after the first second: RMS total, largest, the truth inside the 90 % region; after 5 s: largest): 1.1-1.8 deg,
    2.7-9.3, 100 %; 1.6-3.6 deg (1.4-2.3, 3.8-13.7, 100 %, 1.9-3.9 before the aided and raw low-passes started as
    running means, fuser/model/pair_lowpass.py). Before (2026-12-06) only the 28-s start found it (4.1 deg, 98 %); from 22, 25, 31,
    34 and 40 s the estimate stayed 7-21 deg RMS off (largest 15-57) reporting 3.5-5.4, inside the 90 % region on
    0-89 % of the ticks. The truth is JSBSim's."""
    flight = FLIGHTS["fixedwing"]()
    start = int(np.searchsorted(flight.t_ns, flight.t_ns[0] + start_s * 1e9))
    counters: dict = {}
    cut = flight.cut(start, len(flight.t_ns))
    rms, level = _fly(cut, FuserConfig(), after_s=1.0, counters=counters)
    settled, _ = _fly(cut, FuserConfig(), after_s=5.0)
    assert counters.get("gnss_restart", 0) >= 1, counters
    assert rms["total"] < TOTAL_BOUND_DEG["fixedwing"] and np.mean(level <= 0.9) >= 0.85, (rms, np.mean(level <= 0.9))
    assert settled["max"] < 5.0, settled


def test_a_start_in_a_sustained_turn_without_gnss_says_it_cannot_see():
    """The same start without GNSS: nothing shows the fuser the turn but the specific force's norm, and the estimate
    stays on the bank's vertical (30 deg off). What it reports must say so: measured, the truth inside the 90 %
    region on 94 % of the ticks after 5 s (33 % while a norm learnt in the turn could hide it)."""
    flight = FLIGHTS["fixedwing"]()
    start = int(np.searchsorted(flight.t_ns, flight.t_ns[0] + 28e9))
    rms, level = _fly(flight.cut(start, len(flight.t_ns)), FuserConfig().replace(gnss={"enabled": False}), after_s=5.0)
    assert rms["tilt"] > 20.0, rms  # the physics: without the turn's acceleration the down is the bank's
    assert np.mean(level <= 0.9) >= 0.85, np.mean(level <= 0.9)


@pytest.mark.parametrize("gnss", [True, False], ids=["aided", "alone"])
def test_a_faster_loop_is_not_less_accurate(gnss):
    """The multirotor's first 30 s fused by a 100 Hz and a 200 Hz loop, against the simulator's truth: the faster
    loop's RMS total is within 15 % of the slower one's (the filter gathers the same evidence per second at any
    rate). It was not: at 200 Hz the fast start converged on three raw readings in 15 ms (their sigma was per
    reading, ``accel.sigma_rad``, ``mag.sigma_rad``), started 1-2 deg off in heading, and the bias feedback learnt
    that transient as a z bias: 1.10 -> 1.50 deg with GNSS, 2.89 -> 4.40 without (``updates.fast_start_interval_s``
    now counts the fast start's readings per 10 ms)."""
    flight = FLIGHTS["multirotor"]()
    rms = {rate: _fly(flight, FuserConfig().replace(rate_hz=rate, gnss={"enabled": gnss}))[0]["total"] for rate in (100.0, 200.0)}
    assert rms[200.0] <= 1.15 * rms[100.0], rms


def _one_fix_in(flight, n: int) -> Iterator[tuple[int, list]]:
    """The flight's deliveries with one GNSS fix in ``n`` (10: a 1 Hz receiver)."""
    fixes = 0
    for receive_ns, samples in received(flight):
        kept = []
        for s in samples:
            if isinstance(s, GnssSample):
                fixes += 1
                if fixes % n:
                    continue
            kept.append(s)
        yield receive_ns, kept


@pytest.mark.parametrize("one_in", [10, 5, 2], ids=["1 Hz", "2 Hz", "5 Hz"])
def test_with_slow_fixes_the_fixed_wing_meets_its_bounds_and_is_not_overconfident(one_in):
    """The Cessna's 60 s with a 1, 2 and 5 Hz receiver (one fix in ten, five, two; 10 Hz: 2.3 deg, 100 %). Measured
    2026-12-07: 11.5 deg off reporting 3.1 (the truth inside the 90 % region on 29 % of the ticks), 1.0 deg (100 %),
    2.9 deg (82 %); since the GNSS check and the running-mean start (2026-12-07, later): 11.5 deg reporting 4.9 (48 %),
    1.0 deg (100 %), 2.9 deg (81 %); the 1-Hz error is a rotation about the turn's lift axis, which no GNSS
    acceleration shows (fuser/model/velocity_check.py). The aided bias feedback feeds back the whole correction of the ticks with a pair of fixes: it
    learns the heading's convergence in the first seconds as a z bias (0.9 deg/s off at 1 Hz) and sees the
    magnetometer's corrections only once a pair. Without the feedback (``[fuser.bias] feedback_enabled = false``)
    1.7 deg, 100 % at 1 Hz. Tried and not kept: learning the bias's heading row from every magnetometer reading by
    its Kalman filter while GNSS aids (2.0, 1.1, 1.2, 1.4 deg at 1, 2, 5, 10 Hz, all 100 %), which regressed the
    multirotor's short flights (seeds 0, 3, 7: mean 2.40 -> 2.60 deg) and the 4-min flights of the README's table
    (the Cessna 1.74 -> 2.08): it learnt the z bias 0.2-0.45 deg/s wrong for tens of seconds reporting 0.08 deg/s,
    the heading corrections carrying the tilt of the accelerometer's unestimated bias through the field's dip.

    Since a magnetometer reading alone (between the aided ones) feeds its heading correction back too, critically
    damped against the heading correction's own time constant (:func:`fuser.model.bias.heading_feedback`; only
    the aided readings' ticks were, so the z bias stayed 0.35 deg/s off through the flight even at 10 Hz): 2.75,
    0.92, 0.92 deg at 1, 2 and 5 Hz (10 Hz: 0.89), the truth inside the 90 % region on 100 % of the ticks in each."""
    flight = FLIGHTS["fixedwing"]()
    rms, level = _fly(flight, FuserConfig(), deliveries=_one_fix_in(flight, one_in))
    assert rms["total"] < TOTAL_BOUND_DEG["fixedwing"] and rms["tilt"] < TILT_BOUND_DEG["fixedwing"], rms
    assert np.mean(level <= 0.9) >= 0.85, (np.mean(level <= 0.9), rms)
