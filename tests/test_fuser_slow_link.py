"""Slow links: the autopilot's attitude fused while the IMU arrives too slowly to carry the estimate.

The stream is what a ground station records from an ArduPilot copter over a telemetry radio (measured on
real logs, issue 13): three IMUs as RAW_IMU, SCALED_IMU2 and SCALED_IMU3 (instances 0, 1, 2, each with its
own bias and noise, the first stamped in microseconds, the others in milliseconds), each at 2.8-3.8 Hz with
jitter, ATTITUDE at 3-4 Hz, all from system 1, received 25-55 ms after sending. The motion is the
simulator's hover and banked turns; the autopilot's attitude is the truth with a slowly wandering error of
1-2 deg (an EKF's) plus a little noise. Everything is encoded with pymavlink and decoded by the project's
decoder, then fused by the loop with the default configuration.
"""

from __future__ import annotations

import numpy as np
import pytest

from core import quaternion as quat
from drivers.mavlink_decode import MavlinkDecoder
from drivers.mavlink_encode import MavlinkEncoder
from drivers.samples import AttitudeSample, ImuSample, SourceId
from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

SECONDS = 24.0
SIM_HZ = 200.0
IMU_MESSAGES = ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3")
DOWN = np.array([0.0, 0.0, 1.0])
LINK_JITTER_MS = 60.0
"""``latency_ms`` for a radio whose latency varies by 30 ms: a tick waits that long for its samples (README)."""


def _autopilot_error(rng: np.random.Generator, n: int) -> np.ndarray:
    """Rotation vectors of an EKF's attitude error at ``SIM_HZ``: each axis a random walk low-passed over 4 s,
    scaled to 1 deg RMS per axis (1.7 deg in all), plus 0.2 deg of white noise."""
    walk = np.cumsum(rng.standard_normal((n, 3)), axis=0)
    a = 1.0 / (4.0 * SIM_HZ)
    slow = np.zeros_like(walk)
    for k in range(1, n):
        slow[k] = slow[k - 1] + a * (walk[k] - slow[k - 1])
    slow -= slow.mean(axis=0)
    slow *= np.radians(1.0) / slow.std(axis=0)
    return slow + np.radians(0.2) * rng.standard_normal((n, 3))


def _times(rng: np.random.Generator, n: int, hz: float) -> np.ndarray:
    """Indices on the simulator's grid of a message sent at about ``hz`` with +-20% jitter, from a random phase."""
    step = SIM_HZ / hz
    k = rng.uniform(0, step) + np.arange(int(n / step) - 1) * step + rng.uniform(-0.2, 0.2, int(n / step) - 1) * step
    return np.unique(np.clip(np.round(k).astype(int), 0, n - 1))


def telemetry_stream(seed: int = 4, other_vehicle: bool = False):
    """(receive_ns, bytes) in arrival order, the true attitude and the autopilot's (both on the IMU grid)."""
    flight = simulate(SimConfig(seed=seed, duration_s=SECONDS, imu_rate_hz=SIM_HZ, attitude_rate_hz=SIM_HZ))
    rng = np.random.default_rng(seed)
    n = len(flight.t_ns)
    q_ap = quat.multiply(flight.q_true, quat.from_rotvec(_autopilot_error(rng, n)))
    sent: list[tuple[int, bytes]] = []
    vehicle = MavlinkEncoder(system=1, component=1)
    src = SourceId("mavlink", 1, 1, 0)
    for instance, message in enumerate(IMU_MESSAGES):
        bias = 0.004 * rng.standard_normal(3)
        for k in _times(rng, n, rng.uniform(2.8, 3.8)):
            gyro = flight.gyro_true_rad_s[k] + bias + 0.003 * rng.standard_normal(3) if instance else flight.gyro_rad_s[k]
            accel = flight.accel_m_s2[k] + (0.03 * rng.standard_normal(3) if instance else 0.0)
            mag = quat.rotate(quat.conjugate(flight.q_true[k]), np.asarray(flight.mag_field_ned_gauss)) + 0.003 * rng.standard_normal(3)
            sample = ImuSample(int(flight.t_ns[k]), tuple(gyro), tuple(accel), tuple(mag), SourceId("mavlink", 1, 1, instance))
            sent.append((int(flight.t_ns[k]), vehicle.encode(sample, message)))
    for k in _times(rng, n, 3.5):
        sent.append((int(flight.t_ns[k]), vehicle.encode(AttitudeSample(int(flight.t_ns[k]), tuple(q_ap[k]), src), "ATTITUDE")))
    sent.sort(key=lambda m: m[0])
    received, last = [], 0
    for t, data in sent:  # a radio keeps the order: each arrives 25-55 ms after it was sent, never before the previous
        last = max(last, t + int(rng.uniform(25e6, 55e6)))
        received.append((last, data))
    if other_vehicle:  # another copter heard on the same ground station (system 2), flying its own programme at 10 Hz
        other = simulate(SimConfig(seed=seed + 1, duration_s=SECONDS, imu_rate_hz=SIM_HZ, boot_time_s=80.0))
        encoder = MavlinkEncoder(system=2, component=1)
        other_rng = np.random.default_rng(seed + 100)
        for k in _times(other_rng, n, 10.0):
            q = quat.multiply(other.q_true[k], quat.from_rotvec([0.0, 2.0, 0.0]))  # tilted far from ours
            sample = ImuSample(int(other.t_ns[k]), tuple(other.gyro_rad_s[k] + [0.0, 0.0, 1.0]), tuple(quat.rotate(quat.conjugate(q), [0, 0, -9.8])),
                               None, SourceId("mavlink", 2, 1, 0))
            received.append((int(flight.t_ns[k]) + int(other_rng.uniform(25e6, 55e6)), encoder.encode(sample, "RAW_IMU")))
        received.sort(key=lambda m: m[0])
    return received, flight, q_ap


def _fuse(received, config: FuserConfig):
    decoder = MavlinkDecoder()
    loop = FusionLoop(config)
    estimates = []
    for receive_ns, data in received:
        estimates += loop.advance(receive_ns)
        for s in decoder.feed(data):
            loop.push(s, receive_ns)
    estimates += loop.flush()
    return loop, decoder, estimates


def _tilt_deg(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Angle between world down seen in the two body frames (independent of heading)."""
    a, b = quat.rotate(quat.conjugate(q), DOWN), quat.rotate(quat.conjugate(ref), DOWN)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def _at(t_grid: np.ndarray, q: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    """``q`` (on the grid ``t_grid``) at times ``t_ns``, by the nearest grid point (the grid is 5 ms)."""
    return q[np.clip(np.searchsorted(t_grid, t_ns), 0, len(t_grid) - 1)]


@pytest.fixture(scope="module")
def telemetry():
    received, flight, q_ap = telemetry_stream()
    config = FuserConfig(latency_ms=LINK_JITTER_MS).replace(mag={"field_ned_gauss": flight.mag_field_ned_gauss})
    return flight, q_ap, _fuse(received, config), _fuse(received, config.replace(attitude={"mode": "off"}))


def test_the_stream_is_a_telemetry_link(telemetry):
    """The data is what the test says: three IMU instances and the attitude at 2.8-4 Hz each."""
    _, _, (loop, decoder, _), _ = telemetry
    assert decoder.stats["accepted"] > 0.99 * sum(1 for _ in telemetry_stream()[0])
    rate = loop.model.state.gyro.track.interval_s
    assert 1.0 / rate < 15.0  # the three together, about 10 Hz
    assert loop.counters["late"] == 0


def test_on_a_telemetry_link_the_estimate_follows_the_autopilot_in_tilt(telemetry):
    flight, q_ap, (_, _, estimates), _ = telemetry
    est = [e for e in estimates if e.sensor_t_ns is not None and e.sensor_t_ns >= flight.t_ns[0] + 5e9]
    t = np.array([e.sensor_t_ns for e in est])
    q = np.array([e.q_wxyz for e in est])
    unc = np.array([e.uncertainty_deg for e in est])
    tilt_ap = _tilt_deg(q, _at(flight.t_ns, q_ap, t))
    tilt_true = _tilt_deg(q, _at(flight.t_ns, flight.q_true, t))
    print(f"\ntilt against the autopilot: median {np.median(tilt_ap):.2f}, p90 {np.percentile(tilt_ap, 90):.2f}, max {tilt_ap.max():.2f} deg; "
          f"against the truth: median {np.median(tilt_true):.2f}, p90 {np.percentile(tilt_true, 90):.2f} deg; "
          f"reported uncertainty median {np.median(unc):.2f}, max {unc.max():.2f} deg")
    assert np.median(tilt_ap) < 3.0 and np.percentile(tilt_ap, 90) < 8.0
    assert unc.max() < 10.0  # not tens of degrees while attitude and IMU messages arrive
    total_true = np.degrees(quat.angular_distance(q, _at(flight.t_ns, flight.q_true, t)))
    assert np.mean(total_true < 2.0 * unc) > 0.9  # and what it reports covers its actual error


def test_without_the_attitude_the_slow_imu_alone_does_worse_and_says_so(telemetry):
    """``--no-attitude`` on the same stream: the policy, not luck, is what makes the difference."""
    flight, _, (_, _, fused), (loop, _, alone) = telemetry
    assert loop.model.counters["attitude_unused"] > 50

    def p90(estimates):
        est = [e for e in estimates if e.sensor_t_ns is not None and e.sensor_t_ns >= flight.t_ns[0] + 5e9]
        t = np.array([e.sensor_t_ns for e in est])
        return np.percentile(np.degrees(quat.angular_distance(np.array([e.q_wxyz for e in est]), _at(flight.t_ns, flight.q_true, t))), 90)

    assert p90(alone) > p90(fused)


def test_imus_of_another_vehicle_are_never_averaged_in():
    received, flight, q_ap = telemetry_stream(other_vehicle=True)
    config = FuserConfig(latency_ms=LINK_JITTER_MS).replace(mag={"field_ned_gauss": flight.mag_field_ned_gauss})
    loop, decoder, estimates = _fuse(received, config)
    _, _, alone = _fuse(telemetry_stream()[0], config)
    assert loop.counters["other_vehicle"] > 150  # system 2's 10 Hz for 24 s, counted and dropped
    assert loop.reference_imu == SourceId("mavlink", 1, 1, 0)
    by_tick = {e.t_ns: e.q_wxyz for e in alone}
    both = [(e.q_wxyz, by_tick[e.t_ns]) for e in estimates if e.t_ns in by_tick]
    assert len(both) > 0.9 * len(alone)
    assert all(a == b for a, b in both)  # the other vehicle changed nothing, bit for bit
