"""GNSS velocity aiding, each decoder path into the model and each GNSS fault, scored against the simulator's truth.

The flight: the simulated multirotor's programme for 20 s at 200 Hz (hover, then from 10 s banked turns at
20 deg of bank and 0.5 rad/s, the multirotor drifting at 4-6 m/s), its GNSS at 10 Hz measured 0.15 s before
it is sent. In the turns the accelerometer reads thrust, not gravity: without GNSS velocity the tilt is 3.5-4
deg off there; with it the world acceleration is taken out. The tilt is scored over 12-20 s against the truth
(the angle between the true and the estimated down), independent of the filter. The IMU goes into the loop
as the simulator's samples (the decoders' IMU paths have their own tests); the GNSS goes through the decoder
under test, built by the project's encoders from the simulator's fixes and decoded by the real drivers.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from core import quaternion as quat
from drivers.dronecan_decode import DroneCanDecoder
from drivers.dronecan_encode import encode_dronecan
from drivers.mavlink_decode import MavlinkDecoder
from drivers.mavlink_encode import MavlinkEncoder
from drivers.samples import GnssSample, ImuSample, SourceId
from drivers.scenarios import scenario
from drivers.sim import SIM_SOURCE, SimConfig, samples, simulate
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

SIM = SimConfig(seed=1, duration_s=20.0, imu_rate_hz=200.0)
FLIGHT = simulate(SIM)
LINK_NS = 1_000_000
SCORED_FROM_S = 12.0
AIDED_TILT_DEG = 1.0
"""RMS tilt over the turns with GNSS aiding: measured 0.61-0.63 deg on every path."""
UNAIDED_FACTOR = 3.0
"""Without GNSS the same turns are at least this many times further off than with it (measured 2.8 deg against
0.62: 4.5 times; 3.9 deg before the bias was learnt in motion without GNSS): what the aiding is for."""
DOWN = np.array([0.0, 0.0, 1.0])


def _encoded(path: str, flight=FLIGHT):
    """Per IMU tick: (time, the IMU samples, the GNSS samples after the decoder of ``path``)."""
    mavlink, can = MavlinkDecoder(), DroneCanDecoder()
    encoder = MavlinkEncoder(1, 1)
    node = SourceId("dronecan", 10, 0, 0)
    tid = 0
    out = []
    for t, _, tick in samples(flight, gnss_solution=path == "GLOBAL_POSITION_INT"):
        imu = [s for s in tick if isinstance(s, ImuSample)]
        gnss: list = []
        for s in tick:
            if not isinstance(s, GnssSample):
                continue
            if path == "dronecan":
                gnss += [x for frame in encode_dronecan(s, node.system, tid) for x in can.feed(frame)]
                tid += 1
            else:
                gnss += mavlink.feed(encoder.encode(s, path))
        out.append((t, imu, gnss))
    assert all(isinstance(s, GnssSample) for _, _, g in out for s in g)
    return out


def _fly(ticks, config: FuserConfig = FuserConfig(), flight=FLIGHT, since_s: float = SCORED_FROM_S):
    """The ticks through the loop, each received ``LINK_NS`` after it was sent; (RMS tilt from ``since_s``, the loop,
    the estimates)."""
    loop = FusionLoop(config)
    estimates = []
    for t, imu, gnss in ticks:
        estimates += loop.advance(t + LINK_NS)
        for s in imu + gnss:
            loop.push(s, t + LINK_NS)
    estimates += loop.flush()
    return _tilt_after(estimates, since_s, flight), loop, estimates


def _tilt_after(estimates, since_s: float, flight=FLIGHT) -> float:
    """RMS tilt error (deg) of the estimates from ``since_s`` into the flight, against its truth."""
    est = [e for e in estimates if e.sensor_t_ns is not None and e.sensor_t_ns >= flight.t_ns[0] + since_s * 1e9]
    t = np.array([e.sensor_t_ns for e in est])
    truth = flight.q_true[np.clip(np.searchsorted(flight.t_ns, t), 0, len(flight.t_ns) - 1)]
    q = np.array([e.q_wxyz for e in est])
    tilt = np.degrees(np.arccos(np.clip(np.sum(quat.rotate(quat.conjugate(q), DOWN) * quat.rotate(quat.conjugate(truth), DOWN), axis=1), -1, 1)))
    return float(np.sqrt(np.mean(tilt**2)))


def _aiding(estimates) -> set:
    return {d.get("aiding") for e in estimates for d in e.diagnostics if d["update"] == "gravity"}


@pytest.fixture(scope="module")
def raw_int():
    return _encoded("GPS_RAW_INT")


@pytest.fixture(scope="module")
def clean(raw_int):
    """The GPS_RAW_INT flight fused as it is: the reference for the faults."""
    return _fly(raw_int)


def test_without_gnss_the_turns_are_off(raw_int, clean):
    tilt, loop, estimates = _fly(raw_int, FuserConfig().replace(gnss={"enabled": False}))
    assert tilt > UNAIDED_FACTOR * clean[0], (tilt, clean[0])
    assert _aiding(estimates) == {None} and "gnss_fused" not in loop.model.counters


def test_gps_raw_int_aids_the_horizontal_components_only(clean):
    """GPS_RAW_INT: ground speed and course, no vertical velocity."""
    tilt, loop, estimates = clean
    assert tilt < AIDED_TILT_DEG, tilt
    assert _aiding(estimates) >= {"gnss_horizontal"} and "gnss" not in _aiding(estimates)
    assert loop.model.counters["gnss_fused"] > 0.9 * 10 * (SIM.duration_s - 3.0)  # every fix from convergence on


@pytest.mark.parametrize("path", ["GLOBAL_POSITION_INT", "dronecan"])
def test_a_full_ned_velocity_aids_in_three_dimensions(path):
    """GLOBAL_POSITION_INT: the autopilot's solution, its velocity at the send time (no latency); DroneCAN Fix2:
    the receiver's fix with its velocity covariance, 0.15 s old."""
    tilt, loop, estimates = _fly(_encoded(path))
    assert tilt < AIDED_TILT_DEG, tilt
    assert "gnss" in _aiding(estimates) and "gnss_horizontal" not in _aiding(estimates)
    assert loop.model.counters["gnss_fused"] > 0.9 * 10 * (SIM.duration_s - 3.0)
    assert not {k for k in loop.model.counters if k.startswith("gnss_") and k not in ("gnss_fused", "gnss_gap")}


def test_the_latency_is_compensated():
    """The receiver's fix is 0.15 s old when it arrives. In the aggressive manoeuvres (the acceleration swinging
    by 8 m/s^2 at 1.3 Hz) a wrong latency shows: measured 0.62 deg RMS tilt at the right 150 ms, 2.1 deg with 0,
    2.8 deg with 300 ms."""
    flight = scenario("aggressive", seed=1, imu_rate_hz=200.0)
    ticks = _encoded("GPS_INPUT", flight)
    right, _, _ = _fly(ticks, flight=flight, since_s=5.0)
    for wrong_ms in (0.0, 300.0):
        wrong, _, _ = _fly(ticks, FuserConfig().replace(gnss={"latency_ms": wrong_ms}), flight, 5.0)
        assert right < AIDED_TILT_DEG and wrong > 2.0 * right, (right, wrong_ms, wrong)


def test_two_hertz_fixes_aid_too():
    flight = simulate(dataclasses.replace(SIM, gnss_rate_hz=2.0))
    ticks = [(t, [s for s in tick if isinstance(s, ImuSample)], [s for s in tick if isinstance(s, GnssSample)]) for t, _, tick in samples(flight)]
    tilt, loop, _ = _fly(ticks)
    assert tilt < AIDED_TILT_DEG, tilt
    assert 0.9 * 2 * (SIM.duration_s - 3.0) < loop.model.counters["gnss_fused"] <= 2 * SIM.duration_s


# -- faults ---------------------------------------------------------------------------------------------------

def _with(ticks, change):
    """``ticks`` with each GNSS sample replaced by ``change(sample, seconds into the flight)`` (None: dropped)."""
    t0 = FLIGHT.t_ns[0]
    out = []
    for t, imu, gnss in ticks:
        changed = [change(s, (s.t_ns - t0) * 1e-9) for s in gnss]
        out.append((t, imu, [s for s in changed if s is not None]))
    return out


def test_no_fix_for_two_seconds(raw_int):
    """13-15 s, in the turns: the receiver reports no fix (fix type 1, no velocity, no position). Each message is
    counted; the aiding ends a second after the last pair and the plain update takes over, drifting towards the
    turn's false vertical (3.7 deg) as it does without GNSS; the fixes back, the low-pass starts again from the
    first pair and the tilt is back within 3-5 s (the correction's time constant is 3 s)."""
    ticks = _with(raw_int, lambda s, t: dataclasses.replace(s, fix_type=1, vel_ned_m_s=None, lat_deg=None, lon_deg=None, alt_m=None)
                  if 13.0 <= t < 15.0 else s)
    _, loop, estimates = _fly(ticks)
    c = loop.model.counters
    assert c["gnss_no_fix"] == 20 and c["gnss_lost"] == 1, c
    during = max(_tilt_after([e], 0.0) for e in estimates if 14.0e9 <= e.t_ns - FLIGHT.t_ns[0] < 16.0e9)
    assert during > 2.0  # the plain update in the turn
    assert _tilt_after(estimates, 18.0) < min(2.0, 0.5 * during)  # aided again once the fixes are back


def test_a_velocity_jump_is_kept_out(raw_int, clean):
    """From 15 s on the receiver's velocity is 3 m/s off to the north (its solution jumped: a reset, multipath):
    the pair across the jump, 30 m/s^2 off the accelerometer's acceleration, is gated and the ones after it are
    fine; the estimate does not notice. Without the gate the jump would sit in the low-pass for seconds."""
    def jumped(s, t):
        return dataclasses.replace(s, vel_ned_m_s=(s.vel_ned_m_s[0] + 3.0, s.vel_ned_m_s[1], s.vel_ned_m_s[2])) if t >= 15.0 else s
    ticks = _with(raw_int, jumped)
    tilt, loop, estimates = _fly(ticks)
    assert loop.model.counters["gnss_jump"] == 1
    (jump,) = [d for e in estimates for d in e.diagnostics if d["update"] == "velocity" and d["reason"] == "jump"]
    assert jump["accel_innovation_m_s2"] == pytest.approx(30.0, abs=3.0) and jump["test_ratio"] > 1.0
    assert tilt < clean[0] + 0.1, (tilt, clean[0])
    ungated, _, _ = _fly(ticks, FuserConfig().replace(gnss={"gate_sigma": 1e6}))
    assert ungated > tilt + 0.5, (ungated, tilt)


def test_the_stream_stops(raw_int):
    """No fix after 15 s: the aiding ends once the last pair is a second old (counted once); the plain update
    carries on, as without GNSS."""
    ticks = _with(raw_int, lambda s, t: None if t >= 15.0 else s)
    _, loop, estimates = _fly(ticks)
    assert loop.model.counters["gnss_lost"] == 1
    last_aided = max(e.t_ns for e in estimates for d in e.diagnostics if d.get("aiding"))
    assert (last_aided - FLIGHT.t_ns[0] - LINK_NS) * 1e-9 == pytest.approx(14.9 + 0.15, abs=0.02)  # the last fix, 0.15 s late
    plain = [e for e in estimates if last_aided + 1_050_000_000 < e.t_ns <= FLIGHT.t_ns[-1]]  # max_age_s later
    assert plain and all(any(d["update"] == "gravity" and "aiding" not in d for d in e.diagnostics) for e in plain)


def test_a_stale_receiver_repeating_its_last_solution(raw_int, clean):
    """14-15 s: the receiver sends its 14.0 s velocity again with every new time stamp (frozen): each repeat is
    counted stale and not differenced (a zero acceleration, then the whole change at once, otherwise); the fix
    after it pairs with the last new one over the longer interval."""
    frozen = {}

    def freeze(s, t):
        if 14.0 <= t < 15.0:
            frozen.setdefault("v", s.vel_ned_m_s)
            return dataclasses.replace(s, vel_ned_m_s=frozen["v"])
        return s
    tilt, loop, estimates = _fly(_with(raw_int, freeze))
    assert loop.model.counters["gnss_stale"] == 9
    after = [d for e in estimates for d in e.diagnostics if d["update"] == "velocity" and d["outcome"] == "fused"
             and d["interval_s"] > 0.5]
    assert len(after) == 1 and after[0]["interval_s"] == pytest.approx(1.0, abs=0.01)
    assert tilt < clean[0] + 0.1, (tilt, clean[0])


def test_gnss_of_another_vehicle_is_not_fused(raw_int):
    """A second system's GNSS on the same link (its fixes 3 m/s off): dropped by the loop and counted."""
    other = [(t, imu, gnss + [dataclasses.replace(s, source=SourceId("mavlink", 2, 1, 0),
                                                  vel_ned_m_s=tuple(v + 3.0 for v in s.vel_ned_m_s)) for s in gnss])
             for t, imu, gnss in raw_int]
    mavlink_imu = [(t, [dataclasses.replace(s, source=SourceId("mavlink", 1, 1, 0)) for s in imu], gnss) for t, imu, gnss in other]
    tilt, loop, _ = _fly(mavlink_imu)
    assert loop.counters["other_vehicle"] == sum(len(g) for _, _, g in raw_int)
    assert tilt < AIDED_TILT_DEG
    assert SIM_SOURCE.transport == "sim"  # the original flight's IMU is on another transport: that is why it is re-sourced here


def test_a_vehicle_whose_gnss_stopped_in_flight_is_not_moving_for_ever():
    """The last fix said 5 m/s; with no fix since, the vehicle counts as moving (rest detection off) while that fix
    is fresh at the tick (``max_age_s`` plus the receiver's latency after it was measured), not for ever: after a
    GNSS loss in flight and a landing the rest detector must run again. Before, a stream was compared with the
    newest fix of the kept streams, its own, so it stayed moving."""
    from fuser.model.diagnostics import DIAGNOSTIC
    from fuser.model.state import initial_state
    from fuser.model.velocity import track_velocity
    from model_records import gnss_input, params, part

    cfg = FuserConfig()
    p = params(cfg)
    measured = 10_000_000_000
    fresh_ns = round((cfg.gnss.max_age_s + cfg.gnss.latency_ms * 1e-3) * 1e9)

    def moving_at(tick_ns: int) -> bool:
        state = initial_state(cfg)  # a fresh one each time: the stream's last fix, 5 m/s north, in slot 0
        v = state.velocity
        v.stream_seen[0], v.stream_measured_ns[0], v.stream_vel_ned_m_s[0] = 1, measured, (5.0, 0.0, 0.0)
        v.stream_vertical[0], v.stream_noise_m_s[0] = 1, 0.3
        track, _ = track_velocity(p.gnss, p.accel, p.updates, v, state.knots_ns, state.knots, gnss_input([]), part("gravity"), False,
                                  (0.0, 0.0, 0.0), tick_ns, 10_000_000, tuple(quat.IDENTITY), 90.0, 90.0, 3.0, False,
                                  np.zeros(1, DIAGNOSTIC), 0)
        return track.moving

    assert moving_at(measured + fresh_ns)
    assert not moving_at(measured + fresh_ns + 10_000_000)
    assert not moving_at(measured + 60_000_000_000)
