"""IMU at any rate: the attitude is carried over the whole of every tick, whatever the IMU rate against the loop's.

A yaw turn whose rate rises and falls smoothly, ``w(t) = w_max (1 - cos(2 pi t / T)) / 2`` for ``T``
seconds, turns by exactly ``w_max T / 2`` (closed form). The IMU samples that rate at 25-400 Hz, the loop
ticks at 50-400 Hz; the turn the estimate makes must be within 2% of the true one. The attitude is first
fixed by an autopilot attitude (then no more is sent), the sensor is level and nothing but the gyro sees a
rotation about down, so the turn is the gyro's alone.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import AttitudeSample, ImuSample
from fuser.config import AttitudeSettings, FuserConfig, MagSettings
from fuser.loop import FusionLoop
from fuser.model.propagation import integrate_gyro
from fuser.model.tick import IMU_INPUT
from fusion_inputs import GRAVITY_M_S2, SRC
from model_records import params, part

W_MAX_RAD_S = 1.0
TURN_S = 2.0
TRUE_TURN_RAD = W_MAX_RAD_S * TURN_S / 2.0
START_S, SETTLE_S = 0.5, 0.3
LINK_NS = 1_000_000
BOOT_NS = 12_345_678_901
"""The IMU's clock: its own boot time, not the loop's, and a sample phase that the turn does not start on."""
PHASE = 0.37


def _rate(t_s: float) -> float:
    x = t_s - START_S
    return 0.5 * W_MAX_RAD_S * (1.0 - math.cos(2.0 * math.pi * x / TURN_S)) if 0.0 <= x <= TURN_S else 0.0


def _yaw_at(t_s: float) -> float:
    """Closed form of the integral of ``_rate``."""
    x = min(max(t_s - START_S, 0.0), TURN_S)
    return 0.5 * W_MAX_RAD_S * (x - TURN_S / (2.0 * math.pi) * math.sin(2.0 * math.pi * x / TURN_S))


def _turn(imu_hz: float, loop_hz: float) -> float:
    """Yaw the estimate turned from the start of the turn to its end (rad)."""
    loop = FusionLoop(FuserConfig(rate_hz=loop_hz, mag=MagSettings(enabled=False), attitude=AttitudeSettings(mode="always")))
    level = (0.0, 0.0, -GRAVITY_M_S2)
    events = []
    n = int((START_S + TURN_S + SETTLE_S) * imu_hz)
    for k in range(1, n + 1):
        t = (k + PHASE) / imu_hz
        t_ns = BOOT_NS + round(t * 1e9)
        events.append((t_ns, ImuSample(t_ns, (0.0, 0.0, _rate(t)), level, None, SRC)))
    for k in range(1, int(START_S * 50)):  # the autopilot's attitude at 50 Hz, only before the turn
        t_ns = BOOT_NS + round(k / 50 * 1e9)
        events.append((t_ns, AttitudeSample(t_ns, tuple(quat.from_rotvec([0.0, 0.0, _yaw_at(k / 50)])), SRC)))
    estimates = []
    for t_ns, sample in sorted(events, key=lambda e: e[0]):
        estimates += loop.advance(t_ns + LINK_NS)
        loop.push(sample, t_ns + LINK_NS)
    estimates += loop.flush()
    yaw = {e.sensor_t_ns - BOOT_NS: e.euler_deg[2] for e in estimates if e.sensor_t_ns is not None}
    before = max(t for t in yaw if t <= START_S * 1e9)
    after = max(t for t in yaw if t <= (START_S + TURN_S + SETTLE_S) * 1e9)
    return math.radians(math.remainder(yaw[after] - yaw[before], 360.0))


@pytest.mark.parametrize("imu_hz", [25.0, 50.0, 200.0 / 3.0, 100.0, 200.0, 400.0])
@pytest.mark.parametrize("loop_hz", [50.0, 100.0, 200.0, 400.0])
def test_a_turn_is_integrated_completely_at_any_imu_and_loop_rate(imu_hz, loop_hz):
    turned = _turn(imu_hz, loop_hz)
    assert abs(turned / TRUE_TURN_RAD - 1.0) < 0.02, f"{100 * turned / TRUE_TURN_RAD:.1f}% of the turn"


def _samples(*placed_rate: tuple[int, tuple[float, float, float]]) -> np.ndarray:
    """A tick's IMU samples as the compiled tick reads them (:data:`IMU_INPUT`): each (placed time in ns, gyro rate),
    level, one IMU."""
    out = np.zeros(len(placed_rate), IMU_INPUT)
    for row, (t_ns, rate) in zip(out, placed_rate):
        row["placed_ns"], row["gyro_rad_s"], row["accel_m_s2"] = t_ns, rate, (0.0, 0.0, -9.8)
    return out


def test_a_tick_without_a_sample_rotates_by_the_held_rate_and_the_next_sample_completes_the_interval():
    """25 Hz constant-rate samples under a 100 Hz loop: the three ticks after a sample hold its rate; the
    sample closing the interval applies the trapezoid minus what the hold applied (hand-worked)."""
    gyro = params().gyro
    state = part("gyro")  # no sample yet: its track is changed in place by each tick
    first = integrate_gyro(gyro, state, _samples((0, (0.0, 0.0, 0.2))), -10_000_000, 0)
    rotations = []
    for k in range(1, 5):
        end = k * 10_000_000
        sample = _samples((40_000_000, (0.0, 0.0, 0.6))) if k == 4 else _samples()
        motion = integrate_gyro(gyro, state, sample, end - 10_000_000, end)
        rotations.append(motion.raw_rotation_rad[2])
        assert motion.held == (k < 4)
    np.testing.assert_allclose(rotations[:3], [0.002, 0.002, 0.002])  # 0.2 rad/s held for 10 ms
    # the interval 0-40 ms by the trapezoid is (0.2 + 0.6) / 2 * 0.04 = 0.016 rad; 0.006 of it was held
    np.testing.assert_allclose(sum(rotations), 0.016)
    assert first.gap_s == pytest.approx(0.01)  # before the first sample the rate is unknown
    # held for 10 ms at the end of a sample: published-only error s^2 h^3 / 3
    assert motion.hold_variance_rad2 == 0.0  # the last sample lies at the tick's end
    assert state.has_track and state.track.last_ns == 40_000_000 and tuple(state.track.last_rate_rad_s) == (0.0, 0.0, 0.6)


def test_a_hold_runs_out_after_the_longest_interval_and_the_rest_is_a_gap():
    from fuser.config import GyroSettings

    gyro = params(FuserConfig(gyro=GyroSettings(max_interval_s=0.03, rate_walk_rad_s_rt_s=2.0))).gyro
    state = part("gyro")
    integrate_gyro(gyro, state, _samples((0, (0.1, 0.0, 0.0))), -10_000_000, 0)
    held = gap = closed = 0.0
    for k in range(1, 6):
        motion = integrate_gyro(gyro, state, _samples(), (k - 1) * 10_000_000, k * 10_000_000)
        held += motion.raw_rotation_rad[0]
        gap += motion.gap_s
        closed += motion.closed_variance_rad2
        if k == 2:
            assert motion.hold_variance_rad2 == pytest.approx(4.0 * 0.02**3 / 3.0)  # 20 ms into the hold
    assert held == pytest.approx(0.1 * 0.03)  # held for 30 ms only
    assert gap == pytest.approx(0.02)  # the last 20 ms of the 50 have no rate
    assert closed == pytest.approx(4.0 * 0.03**3 / 3.0)  # the hold's unverified rotation enters the state once


def _closed_variance(rates: np.ndarray, rate_hz: float, times_ns: np.ndarray | None = None) -> float:
    """The variance a gyro stream (one sample per tick) closes into the state and holds for its published state,
    summed over the ticks; ``rates`` (n, 3), one rate per sample, at ``rate_hz`` or at ``times_ns``."""
    gyro, state = params().gyro, part("gyro")
    times = np.arange(len(rates)) * round(1e9 / rate_hz) if times_ns is None else times_ns
    total, start = 0.0, int(times[0]) - 1
    for t, w in zip(times.tolist(), rates):
        motion = integrate_gyro(gyro, state, _samples((t, tuple(float(v) for v in w))), start, t + 1)
        total += motion.closed_variance_rad2 + motion.hold_variance_rad2
        start = t + 1
    return total


def _rough(walk: float, h: float, n: int) -> np.ndarray:
    """A rate whose every axis walks at intensity ``walk`` (rad/s/sqrt(s)), sampled every ``h`` s, pulled back
    towards 0 at 0.5 /s (within the gyro's range, and nearly a random walk over an interval)."""
    rng = np.random.default_rng(7)
    rates = np.zeros((n, 3))
    for k in range(1, n):
        rates[k] = rates[k - 1] * math.exp(-0.5 * h) + rng.normal(0.0, walk * math.sqrt(h), 3)
    return rates


@pytest.mark.parametrize("walk", [2.0, 5.0])
def test_at_a_telemetry_rate_a_rough_rate_widens_each_interval_by_the_walk_its_samples_show(walk):
    """A rate walking at ``walk`` on every axis, sampled at 4 Hz: the closed variance is the Brownian bridge's
    ``s^2 h^3 / 12`` per interval with ``s`` near the true one (from above: one change of slope is a noisy measure,
    and the window keeps the roughest of its second), not the configured 0.3."""
    h, n = 0.25, 400
    per_interval = _closed_variance(_rough(walk, h, n), 1.0 / h) / (n - 1)
    assert 1.0 < per_interval / (walk**2 * h**3 / 12.0) < 4.0, per_interval / (walk**2 * h**3 / 12.0)


def test_at_a_telemetry_rate_a_steadily_changing_rate_is_not_rough():
    """A rate ramping at 2 rad/s^2 and holding (the entry into a turn), at 4 Hz: every slope the same but at the
    ramp's two ends, so the configured walk is all that is counted but for the second after each (the window)."""
    h = 0.25
    ramp = np.concatenate([np.zeros(8), 2.0 * h * np.arange(1, 9), np.full(40, 16 * h)])
    rates = np.column_stack([ramp, np.zeros_like(ramp), np.zeros_like(ramp)])
    closed = _closed_variance(rates, 1.0 / h)
    configured = 0.3**2 * h**3 / 12.0
    steady = _closed_variance(np.full((len(rates), 3), 1.0), 1.0 / h)
    assert steady == pytest.approx(configured * (len(rates) - 1))
    corner = 2.0**2 / 3.0 / (2.0 / h) * h**3 / 12.0  # a change of slope of 2 rad/s^2 on one axis, at each end
    assert closed == pytest.approx(steady + 2 * 5 * (corner - configured), rel=1e-9)  # the corner's interval, the 4 in its second


def test_sampled_at_50_hz_or_faster_the_samples_roughness_is_not_counted():
    """The same random walk of 10 rad/s/sqrt(s) at 200 Hz: a stream at 5 ms is within ``gyro.smooth_interval_s``
    (the samples follow the rate), so only the configured walk is counted, to the bit."""
    h, n = 0.005, 400
    assert _closed_variance(_rough(10.0, h, n), 1.0 / h) == pytest.approx(0.3**2 * h**3 / 12.0 * (n - 1), rel=1e-12)


def test_a_dropout_in_a_fast_stream_is_not_a_slow_stream():
    """200 Hz with one 30-ms dropout in which the rate steps by 2 rad/s, then 10 s more: the stream's low-passed
    interval stays fast, so the step's change of slope is not taken for unseen motion, then or later (before:
    53 times the configured walk, held for the rest of the flight)."""
    h = 0.005
    times = np.concatenate([np.arange(100), np.arange(106, 2106)]) * 5_000_000
    rates = np.zeros((len(times), 3))
    rates[100:, 0] = 2.0
    dropped = _closed_variance(rates, 1.0 / h, times)
    steady = _closed_variance(np.zeros((len(times), 3)), 1.0 / h, times)
    assert dropped == pytest.approx(steady, rel=1e-12)


def test_at_50_hz_with_jitter_the_samples_roughness_is_not_counted():
    """50 Hz, each interval 20 ms +- 0.5 ms (a real IMU's schedule), the rate walking at 3 rad/s/sqrt(s): the
    configured walk only, as for an exactly regular stream (counted per interval, half of them had exceeded 20 ms:
    3.2 times the variance)."""
    n = 500
    jitter = np.random.default_rng(3).uniform(-500_000, 500_000, n).round().astype(np.int64)
    times = np.arange(n, dtype=np.int64) * 20_000_000 + jitter
    walked = _closed_variance(_rough(3.0, 0.02, n), 50.0, times)
    still = _closed_variance(np.zeros((n, 3)), 50.0, times)
    assert walked == pytest.approx(still, rel=1e-12)
