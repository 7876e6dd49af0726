"""MAVLink out: a pymavlink ground station on loopback receives ATTITUDE_QUATERNION, ATTITUDE and
HEARTBEAT from the fuser's own component, at the set rates, with the values fed in."""

from __future__ import annotations

import dataclasses
import os
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from drivers.samples import ImuSample, SourceId  # noqa: E402
from fuser.errors import FuserError  # noqa: E402
from fuser.mavlink_out import STALE_AFTER_NS, MavlinkOut, MavlinkOutSettings  # noqa: E402
from fuser.record import read_log  # noqa: E402

LOGS = Path(__file__).resolve().parent.parent / "logs"
VEHICLE = SourceId("mavlink", 42, 1, 0)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _feed(seconds: float) -> list[tuple[str, int, object]]:
    """A real fuser run (logs/sim_hover.mcap, 100 Hz estimates, from 50 ms of IMU before the first), its IMU
    re-addressed to system 42: (kind, time on the loop's timeline (an IMU sample's receive time), sample or estimate)."""
    contents = read_log(LOGS / "sim_hover.mcap")
    events = [(r, 0, dataclasses.replace(s, source=VEHICLE)) for s, r in contents.inputs() if isinstance(s, ImuSample)]
    events += [(e.t_ns, 1, e) for e in contents.estimates()]
    events.sort(key=lambda x: (x[0], x[1]))
    t0 = next(t for t, kind, _ in events if kind == 1)
    return [("est" if kind else "imu", t, obj) for t, kind, obj in events if t0 - 50_000_000 <= t < t0 + seconds * 1e9]


def test_a_ground_station_receives_the_fused_attitude_from_its_own_component() -> None:
    port = free_udp_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="common")  # receiver first: udpout drops otherwise
    out = MavlinkOut(MavlinkOutSettings(connection=f"udpout:127.0.0.1:{port}", rate_hz=10.0))
    try:
        sent, gyro = [], (0.0, 0.0, 0.0)
        for kind, t, obj in _feed(3.0):
            if kind == "imu":
                out.write_sample(obj, t)
                gyro = obj.gyro_rad_s
            else:
                before = out.sent
                out.publish_estimate(obj)
                if out.sent > before:
                    sent.append((obj, gyro, out.sent - before))
        assert out.errors == 0
        received: list = []
        deadline = time.monotonic() + 5.0
        while len(received) < out.sent and time.monotonic() < deadline:
            m = gcs.recv_match(blocking=True, timeout=0.2)
            if m is not None and m.get_type() != "BAD_DATA":
                received.append(m)
    finally:
        out.close()
        gcs.close()
    by_type: dict[str, list] = {}
    for m in received:
        by_type.setdefault(m.get_type(), []).append(m)
        assert (m.get_srcSystem(), m.get_srcComponent()) == (42, 197)  # the vehicle's system, a component of its own
        assert m.get_msgbuf()[0] == 0xFD  # MAVLink 2 frames (magic byte)
    # 3 s of estimates at 100 Hz: 30 attitudes at 10 Hz, one heartbeat per second
    assert len(by_type["ATTITUDE_QUATERNION"]) == len(by_type["ATTITUDE"]) == 30
    assert len(by_type["HEARTBEAT"]) == 3
    hb = by_type["HEARTBEAT"][0]
    assert (hb.type, hb.autopilot, hb.system_status) == (18, 8, 4)  # ONBOARD_CONTROLLER, AUTOPILOT_INVALID, ACTIVE
    attitude_ticks = [(e, g) for e, g, n in sent if n >= 2]
    assert [e.t_ns for e, _ in attitude_ticks] == [attitude_ticks[0][0].t_ns + k * 100_000_000 for k in range(30)]
    for (est, g), aq, att in zip(attitude_ticks, by_type["ATTITUDE_QUATERNION"], by_type["ATTITUDE"], strict=True):
        np.testing.assert_allclose([aq.q1, aq.q2, aq.q3, aq.q4], est.q_wxyz, atol=1e-7)  # float32 on the wire
        np.testing.assert_allclose([aq.rollspeed, aq.pitchspeed, aq.yawspeed], g, rtol=1e-6, atol=1e-9)
        assert aq.time_boot_ms == att.time_boot_ms == est.sensor_t_ns // 1_000_000
        w, x, y, z = est.q_wxyz
        yaw, pitch, roll = Rotation.from_quat([x, y, z, w]).as_euler("ZYX")  # independent of the fuser's euler_deg
        np.testing.assert_allclose([att.roll, att.pitch], [roll, pitch], atol=1e-6)
        assert abs((att.yaw - yaw + np.pi) % (2 * np.pi) - np.pi) < 1e-6


def test_settings_are_validated() -> None:
    for kwargs, key in [({"rate_hz": 0}, "mavlink_out.rate_hz"), ({"rate_hz": 1e-300}, "mavlink_out.rate_hz"),  # 1e-300: an overflow
                        ({"system_id": 0}, "mavlink_out.system_id"),
                        ({"component_id": 1}, "mavlink_out.component_id"), ({"component_id": 300}, "mavlink_out.component_id"),
                        ({"connection": "notaconn"}, "mavlink_out.connection"), ({"connection": "udpout:127.0.0.1:99999"},
                                                                                "mavlink_out.connection")]:
        with pytest.raises(ValueError, match=key):
            MavlinkOutSettings(**kwargs)


def test_a_connection_that_cannot_open_raises_at_once_and_a_failed_send_never_raises() -> None:
    with pytest.raises(FuserError, match="cannot open --mavlink-out /dev/no-such-tty: "):
        MavlinkOut(MavlinkOutSettings(connection="/dev/no-such-tty"))
    out = MavlinkOut(MavlinkOutSettings(connection=f"udpout:127.0.0.1:{free_udp_port()}"))

    def unplugged(buf: bytes) -> None:
        raise OSError(5, "Input/output error")

    out._conn.write = unplugged  # a serial adapter pulled out under it
    est = read_log(LOGS / "sim_hover.mcap").estimates()[0]
    out.publish_estimate(est)
    out.close()
    assert out.errors >= 1 and out.error is not None and out.sent == 0


def test_the_attitude_stops_once_the_imu_has_been_silent_for_a_second() -> None:
    """The loop goes on publishing after its input stops (the last rate held): a ground station must not be shown
    that as a fresh attitude. ATTITUDE_QUATERNION and ATTITUDE stop STALE_AFTER_NS after the last IMU sample (the
    heartbeat goes on: the component is alive), and start again with the IMU."""
    out = MavlinkOut(MavlinkOutSettings(connection=f"udpout:127.0.0.1:{free_udp_port()}", rate_hz=10.0))
    mav = out._conn.mav
    attitudes: list[int] = []
    heartbeats: list[int] = []
    now = {"t": 0}
    mav.attitude_quaternion_send = lambda *a, **k: attitudes.append(now["t"])
    mav.heartbeat_send = lambda *a, **k: heartbeats.append(now["t"])
    events = _feed(8.0)
    t0 = events[0][1]
    silent = (t0 + 2_000_000_000, t0 + 6_000_000_000)  # the IMU stops for 4 s, the estimates go on
    last_imu = max(t for kind, t, _ in events if kind == "imu" and t < silent[0])
    try:
        for kind, t, obj in events:
            now["t"] = t
            if kind == "imu" and not silent[0] <= t < silent[1]:
                out.write_sample(obj, t)
            elif kind == "est":
                out.publish_estimate(obj)
    finally:
        out.close()
    during = [t for t in attitudes if silent[0] <= t < silent[1]]
    assert during and max(during) <= last_imu + STALE_AFTER_NS, (during[-1] - last_imu) / 1e9  # 1 s more, then none
    assert len(during) == pytest.approx(10, abs=1)
    assert any(t >= silent[1] for t in attitudes)  # back with the IMU
    assert sum(silent[0] <= t < silent[1] for t in heartbeats) == 4
    assert out.withheld == pytest.approx(30, abs=1) and out.errors == 0
