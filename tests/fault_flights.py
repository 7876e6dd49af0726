"""Simulated flights with a sensor fault the filter cannot see coming, and their scoring against the truth.

Each fault starts 4 s into the simulator's programme, in its hover with small attitude changes (the first
10 s: the banked turns after it would make a recovery without GNSS a test of the accelerometer in turns,
not of the fault), and the recovery is scored until 12 s. The truth is the simulator's:

* ``saturation``: the gyro reads its range, +34.9 rad/s about x, for 2 s (a failed or overwhelmed sensor)
  while the vehicle flies on;
* ``rogue_imu``: a second IMU of the vehicle (instance 1, agreeing with the first before and after, on
  its own clock) sends random data for 4 s;
* ``stuck_imu``: the second IMU's x gyro frozen at 0.5 rad/s for 4 s (close enough to the first's rate that each
  sample passes the per-sample comparison);
* ``attitude_jump``: over a telemetry link (three IMUs at about 3 Hz, the autopilot's ATTITUDE at 3.5 Hz,
  ``test_fuser_slow_link.telemetry_stream``) the autopilot's attitude jumps by 30 deg of roll for 4 s;
* ``bias_step`` (not in :data:`FAULTS`: it never ends): the gyro's x bias grows by 0.05 rad/s at 4 s and stays;
* ``saturation_in_turn``: the same saturated gyro at 12 s, in the programme's sustained banked turns (20 deg of
  bank, 0.5 rad/s), scored until 25 s: the recovery then needs the GNSS velocity (it is fused; without it the
  accelerometer's tilt in a turn is the bank's).

Used by ``tests/test_fuser_admitted_faults.py`` and ``benchmarks/faults.py``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from core import quaternion as quat
from drivers.mavlink_encode import MavlinkEncoder
from drivers.samples import AttitudeSample, ImuSample, SourceId
from drivers.sim import SIM_SOURCE, SimConfig, samples, simulate
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

LINK_NS = 1_000_000
RECOVERED_DEG = 5.0
START_S = 4.0
SCORED_UNTIL_S = 12.0


@dataclass(frozen=True)
class FaultRun:
    """One faulty flight fused: per estimate, its time from the flight's start, error and reported uncertainty."""

    name: str
    t_s: np.ndarray
    error_deg: np.ndarray
    uncertainty_deg: np.ndarray
    start_s: float
    end_s: float
    counters: dict
    scored_until_s: float = SCORED_UNTIL_S

    def window(self, a: float, b: float) -> np.ndarray:
        return (self.t_s >= a) & (self.t_s < b)

    @property
    def recovery_s(self) -> float:
        """Seconds from the fault's end until the error stays under ``RECOVERED_DEG`` up to ``scored_until_s``
        (inf if it never does)."""
        after = self.window(self.end_s, self.scored_until_s)
        bad = np.nonzero(after & (self.error_deg >= RECOVERED_DEG))[0]
        if len(bad) == 0:
            return 0.0
        if bad[-1] == len(self.t_s) - 1:
            return float("inf")
        return float(self.t_s[bad[-1] + 1] - self.end_s)

    def summary(self) -> dict:
        during = self.window(self.start_s, self.end_s)
        before = self.window(self.start_s - 2.0, self.start_s)
        after = self.window(self.end_s, self.scored_until_s)
        return {
            "error_before_deg": float(np.sqrt(np.mean(self.error_deg[before] ** 2))),
            "uncertainty_before_deg": float(np.mean(self.uncertainty_deg[before])),
            "error_during_max_deg": float(self.error_deg[during].max()),
            "error_during_rms_deg": float(np.sqrt(np.mean(self.error_deg[during] ** 2))),
            "uncertainty_during_deg": float(np.mean(self.uncertainty_deg[during])),
            "uncertainty_during_min_deg": float(self.uncertainty_deg[during].min()),
            "recovery_s": self.recovery_s,
            "overconfident_after_s": float(np.sum(after & (self.error_deg > 2.0 * self.uncertainty_deg)) * np.median(np.diff(self.t_s))),
        }


def _fuse(events, config: FuserConfig, flight, name: str, start_s: float, end_s: float, scored_until_s: float = SCORED_UNTIL_S) -> FaultRun:
    loop = FusionLoop(config)
    estimates = []
    for receive_ns, sample in events:
        estimates += loop.advance(receive_ns)
        loop.push(sample, receive_ns)
    estimates += loop.flush()
    last = min(int(flight.t_ns[-1]), int(flight.t_ns[0] + scored_until_s * 1e9))
    est = [e for e in estimates if e.sensor_t_ns is not None and flight.t_ns[0] <= e.sensor_t_ns <= last]
    t = np.array([e.sensor_t_ns for e in est])
    truth = flight.q_true[np.clip(np.searchsorted(flight.t_ns, t), 0, len(flight.t_ns) - 1)]
    error = np.degrees(quat.angular_distance(np.array([e.q_wxyz for e in est]), truth))
    counters = dict(loop.counters) | dict(loop.model.counters)
    return FaultRun(name, (t - flight.t_ns[0]) * 1e-9, error, np.array([e.uncertainty_deg for e in est]), start_s, end_s, counters,
                    scored_until_s)


def saturation(seed: int = 0, start_s: float = START_S, seconds: float = 2.0, scored_until_s: float = SCORED_UNTIL_S,
               config: FuserConfig = FuserConfig(), name: str = "saturated gyro") -> FaultRun:
    flight = simulate(SimConfig(seed=seed, duration_s=scored_until_s, imu_rate_hz=200.0))
    rel = (flight.t_ns - flight.t_ns[0]) * 1e-9
    gyro = flight.gyro_rad_s.copy()
    gyro[(rel >= start_s) & (rel < start_s + seconds), 0] = 34.9
    flight_faulty = dataclasses.replace(flight, gyro_rad_s=gyro)
    events = [(t + LINK_NS, s) for t, _, ss in samples(flight_faulty) for s in ss]
    return _fuse(events, config, flight, name, start_s, start_s + seconds, scored_until_s)


TURN_START_S = 12.0
TURN_SCORED_UNTIL_S = 25.0


def saturation_in_turn(seed: int = 0, gnss: bool = True) -> FaultRun:
    """The saturated gyro for 2 s at 12 s, in the sustained banked turns, with (or without) the GNSS velocity."""
    return saturation(seed, TURN_START_S, 2.0, TURN_SCORED_UNTIL_S, FuserConfig().replace(gnss={"enabled": gnss}),
                      "saturated gyro in a banked turn" + ("" if gnss else ", without GNSS"))


def _second_imu(name: str, faulty, seed: int, start_s: float, seconds: float) -> FaultRun:
    """A second IMU of the vehicle (instance 1, agreeing with the first before and after, on its own clock) whose
    samples from ``start_s`` for ``seconds`` are ``faulty(rng, gyro, accel, mag)``'s."""
    flight = simulate(SimConfig(seed=seed, duration_s=SCORED_UNTIL_S, imu_rate_hz=200.0))
    rng = np.random.default_rng(seed + 11)
    rel = (flight.t_ns - flight.t_ns[0]) * 1e-9
    second = SourceId(SIM_SOURCE.transport, SIM_SOURCE.system, SIM_SOURCE.component, 1)
    bias = 0.006 * rng.standard_normal(3)
    events = []
    for k, (t, _, ss) in enumerate(samples(flight)):
        events += [(t + LINK_NS, s) for s in ss]
        t2 = int(t) + 1_250_000  # its own clock and phase
        gyro = flight.gyro_true_rad_s[k] + bias + 0.003 * rng.standard_normal(3)
        accel = flight.accel_true_m_s2[k] + 0.05 * rng.standard_normal(3)
        mag = flight.mag_true_gauss[k] + 0.003 * rng.standard_normal(3)
        if start_s <= rel[k] < start_s + seconds:
            gyro, accel, mag = faulty(rng, gyro, accel, mag)
        events.append((t2 + LINK_NS, ImuSample(t2, tuple(gyro), tuple(accel), tuple(mag), second)))
    events.sort(key=lambda e: e[0])
    return _fuse(events, FuserConfig(), flight, name, start_s, start_s + seconds)


def rogue_imu(seed: int = 0, start_s: float = START_S, seconds: float = 4.0) -> FaultRun:
    return _second_imu("rogue second IMU",
                       lambda rng, g, a, m: (rng.uniform(-30.0, 30.0, 3), rng.uniform(-50.0, 50.0, 3), rng.uniform(-1.0, 1.0, 3)),
                       seed, start_s, seconds)


def stuck_imu(seed: int = 0, start_s: float = START_S, seconds: float = 4.0) -> FaultRun:
    """The second IMU's x gyro frozen at 0.5 rad/s (within the per-sample tolerance of the first's rate)."""
    return _second_imu("second IMU's x gyro stuck", lambda rng, g, a, m: ((0.5, g[1], g[2]), a, m), seed, start_s, seconds)


BIAS_STEP_RAD_S = 0.05
BIAS_SCORED_UNTIL_S = 30.0


def bias_step(seed: int = 0, step_rad_s: float = BIAS_STEP_RAD_S, gnss: bool = True) -> FaultRun:
    """The gyro's x bias grows by ``step_rad_s`` (2.9 deg/s at the default) at 4 s and stays (a sensor fault, a
    jump with temperature): nothing ends it, so it is scored while it lasts, until 30 s."""
    flight = simulate(SimConfig(seed=seed, duration_s=BIAS_SCORED_UNTIL_S, imu_rate_hz=200.0))
    rel = (flight.t_ns - flight.t_ns[0]) * 1e-9
    gyro = flight.gyro_rad_s.copy()
    gyro[rel >= START_S, 0] += step_rad_s
    events = [(t + LINK_NS, s) for t, _, ss in samples(dataclasses.replace(flight, gyro_rad_s=gyro)) for s in ss]
    return _fuse(events, FuserConfig().replace(gnss={"enabled": gnss}), flight, "gyro bias step" + ("" if gnss else ", without GNSS"),
                 START_S, BIAS_SCORED_UNTIL_S, BIAS_SCORED_UNTIL_S)


def attitude_jump(seed: int = 4, start_s: float = START_S, seconds: float = 4.0, jump_deg: float = 30.0) -> FaultRun:
    from test_fuser_slow_link import LINK_JITTER_MS, telemetry_stream

    from drivers.mavlink_decode import MavlinkDecoder

    received, flight, _ = telemetry_stream(seed)
    decoder = MavlinkDecoder()
    jump = quat.from_rotvec([np.radians(jump_deg), 0.0, 0.0])
    t0 = int(flight.t_ns[0])
    encoder = MavlinkEncoder()
    events = []
    for receive_ns, data in received:
        for s in decoder.feed(data):
            if isinstance(s, AttitudeSample) and start_s <= (s.t_ns - t0) * 1e-9 < start_s + seconds:
                s = AttitudeSample(s.t_ns, tuple(quat.multiply(s.q_wxyz, jump)), s.source)
                (s,) = MavlinkDecoder().feed(encoder.encode(s, "ATTITUDE"))  # as the autopilot would send it
            events.append((receive_ns, s))
    config = FuserConfig(latency_ms=LINK_JITTER_MS).replace(mag={"field_ned_gauss": flight.mag_field_ned_gauss})
    return _fuse(events, config, flight, "attitude source jumps 30 deg", start_s, start_s + seconds)


FAULTS = {"saturation": saturation, "rogue_imu": rogue_imu, "stuck_imu": stuck_imu, "attitude_jump": attitude_jump, "saturation_in_turn": saturation_in_turn}
