"""GNSS velocity from MAVLink: messages built with pymavlink directly, values worked out by hand."""

import math
import os

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from drivers.mavlink_decode import MavlinkDecoder  # noqa: E402
from drivers.mavlink_encode import MavlinkEncoder  # noqa: E402
from drivers.samples import GnssSample, SourceId  # noqa: E402
from fuser.codec import decode_sample, encode_sample, sample_channel  # noqa: E402

MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
UNKNOWN = 0xFFFF


def frame(msg) -> bytes:
    return bytes(msg.pack(MAV))


def gps_raw_int(fix_type=3, vel=1000, cog=9000, vel_acc=250, time_usec=2_000_000):
    # time_usec, fix, lat, lon, alt (mm), eph, epv, vel (cm/s), cog (cdeg), sats, alt_ellipsoid, h_acc, v_acc, vel_acc (mm/s), hdg_acc, yaw
    return mavlink.MAVLink_gps_raw_int_message(time_usec, fix_type, 473977000, 85456000, 488200, 100, 150, vel, cog, 12,
                                               530000, 900, 1500, vel_acc, 0, 0)


def test_gps_raw_int_ground_speed_along_the_course_east():
    (s,) = MavlinkDecoder().feed(frame(gps_raw_int(vel=1000, cog=9000)))  # 10 m/s, course 90 deg: due east
    assert isinstance(s, GnssSample)
    assert s.vel_ned_m_s == pytest.approx((0.0, 10.0, 0.0), abs=1e-12)
    assert s.vertical_velocity is False and s.filtered is False
    assert s.speed_accuracy_m_s == pytest.approx(0.25)
    assert (s.lat_deg, s.lon_deg, s.alt_m) == pytest.approx((47.3977, 8.5456, 488.2))
    assert s.t_ns == 2_000_000_000 and s.fix_type == 3


def test_gps_raw_int_course_south_west():
    (s,) = MavlinkDecoder().feed(frame(gps_raw_int(vel=500, cog=22500)))
    assert s.vel_ned_m_s == pytest.approx((-5 * math.sqrt(0.5), -5 * math.sqrt(0.5), 0.0), abs=1e-12)


@pytest.mark.parametrize("fix_type, vel, cog", [(1, 1000, 9000), (0, 0, 0), (3, UNKNOWN, 9000), (3, 1000, UNKNOWN)])
def test_gps_raw_int_without_a_velocity(fix_type, vel, cog):
    (s,) = MavlinkDecoder().feed(frame(gps_raw_int(fix_type=fix_type, vel=vel, cog=cog)))
    assert s.vel_ned_m_s is None
    assert s.fix_type == fix_type


def test_global_position_int_is_the_autopilots_ned_velocity():
    msg = mavlink.MAVLink_global_position_int_message(7_000, 473977000, 85456000, 488200, 10000, 1234, -560, 70, 18000)
    (s,) = MavlinkDecoder().feed(frame(msg))
    assert s.vel_ned_m_s == pytest.approx((12.34, -5.60, 0.70))
    assert s.vertical_velocity is True and s.filtered is True
    assert s.t_ns == 7_000_000_000


def test_implausible_gnss_is_refused_and_counted():
    decoder = MavlinkDecoder()
    bad_speed = mavlink.MAVLink_global_position_int_message(7_000, 0, 0, 0, 0, 32000, 0, 0, 0)  # 320 m/s north
    bad_position = mavlink.MAVLink_global_position_int_message(8_000, 950000000, 0, 0, 0, 0, 0, 0, 0)  # latitude 95
    assert decoder.feed(frame(bad_speed) + frame(bad_position)) == []
    assert decoder.stats["gnss_velocity_out_of_range"] == 1
    assert decoder.stats["position_out_of_range"] == 1


@pytest.mark.parametrize("message", ["GPS_RAW_INT", "GLOBAL_POSITION_INT"])
def test_encoder_decoder_and_json_round_trip(message):
    sample = GnssSample(5_000_000_000, 3, (3.0, -4.0, 0.5), True, 0.3, 47.3977, 8.5456, 488.2, False, SourceId("mavlink", 1, 1, 0))
    (s,) = MavlinkDecoder().feed(MavlinkEncoder().encode(sample, message))
    assert s.vel_ned_m_s[:2] == pytest.approx((3.0, -4.0), abs=0.01)  # cm/s and cdeg resolution
    assert s.vel_ned_m_s[2] == (pytest.approx(0.5) if message == "GLOBAL_POSITION_INT" else 0.0)
    again, receive_ns = decode_sample(sample_channel(s), encode_sample(s, 42))
    assert again == s and receive_ns == 42
