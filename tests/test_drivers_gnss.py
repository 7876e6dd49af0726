"""GNSS velocity from MAVLink: messages built with pymavlink directly, values worked out by hand."""

import math
import os

import can
import dronecan
import numpy as np
import pytest
from dronecan.transport import Transfer

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from drivers import DroneCanDecoder, encode_dronecan  # noqa: E402
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


# ---------------------------------------------------------------- GPS_INPUT, HIL_GPS (MAVLink), Fix2 (DroneCAN)

IGNORE_VEL_HORIZ, IGNORE_VEL_VERT, IGNORE_SPEED_ACCURACY = 8, 16, 32  # GPS_INPUT_IGNORE_FLAGS, from common.xml


def gps_input(ignore=0, fix_type=3, vn=3.0, ve=-4.0, vd=0.5, speed_accuracy=0.25, gps_id=1):
    # time_usec, gps_id, ignore_flags, time_week_ms, time_week, fix_type, lat, lon (degE7), alt (m), hdop, vdop,
    # vn, ve, vd (m/s), speed_accuracy (m/s), horiz_accuracy, vert_accuracy, satellites_visible, yaw
    return mavlink.MAVLink_gps_input_message(3_000_000, gps_id, ignore, 0, 0, fix_type, 473977000, 85456000, 488.25,
                                             0.8, 1.1, vn, ve, vd, speed_accuracy, 1.5, 2.5, 14, 0)


def test_gps_input_ned_velocity_in_metres_per_second():
    (s,) = MavlinkDecoder().feed(frame(gps_input()))
    assert s.vel_ned_m_s == (3.0, -4.0, 0.5)  # float32 values that are exact
    assert s.vertical_velocity is True and s.filtered is False
    assert s.speed_accuracy_m_s == 0.25
    assert (s.lat_deg, s.lon_deg, s.alt_m) == pytest.approx((47.3977, 8.5456, 488.25))
    assert s.t_ns == 3_000_000_000 and s.source.instance == 1


@pytest.mark.parametrize(
    "ignore, vel, vertical, accuracy",
    [
        (IGNORE_VEL_VERT, (3.0, -4.0, 0.0), False, 0.25),
        (IGNORE_VEL_HORIZ, None, False, 0.25),
        (IGNORE_SPEED_ACCURACY, (3.0, -4.0, 0.5), True, None),
    ],
)
def test_gps_input_fields_switched_off_by_ignore_flags(ignore, vel, vertical, accuracy):
    (s,) = MavlinkDecoder().feed(frame(gps_input(ignore=ignore)))
    assert (s.vel_ned_m_s, s.vertical_velocity, s.speed_accuracy_m_s) == (vel, vertical, accuracy)


def test_gps_input_without_a_fix_has_no_velocity():
    (s,) = MavlinkDecoder().feed(frame(gps_input(fix_type=1)))
    assert s.vel_ned_m_s is None and s.lat_deg is None


def test_hil_gps_ned_velocity_in_centimetres_per_second():
    # time_usec, fix_type, lat, lon (degE7), alt (mm), eph, epv, vel (cm/s), vn, ve, vd (cm/s), cog (cdeg), satellites, id, yaw
    msg = mavlink.MAVLink_hil_gps_message(4_000_000, 3, 473977000, 85456000, 488200, 100, 150, 1360, 1234, -560, 70, 35560, 12, 0, 0)
    (s,) = MavlinkDecoder().feed(frame(msg))
    assert s.vel_ned_m_s == pytest.approx((12.34, -5.60, 0.70), abs=1e-12)
    assert s.vertical_velocity is True and s.speed_accuracy_m_s is None
    assert s.alt_m == pytest.approx(488.2) and s.t_ns == 4_000_000_000


def fix2_frames(node=33, rx_time=10.0, **fields):
    fix = dronecan.TYPENAMES["uavcan.equipment.gnss.Fix2"](**fields)
    transfer = Transfer(payload=fix, source_node_id=node, transfer_id=0, transfer_priority=20)
    return [can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=rx_time) for f in transfer.to_frames()]


def decode_can(frames, decoder=None):
    decoder = decoder or DroneCanDecoder()
    return [s for f in frames for s in decoder.feed(f)]


def stamp(usec):
    return dronecan.TYPENAMES["uavcan.Timestamp"](usec=usec)


def test_fix2_ned_velocity_and_speed_accuracy_from_the_velocity_variances():
    # covariance as 6 variances: position n, e, d (m^2), velocity n, e, d ((m/s)^2); float16 on the wire
    cov = [4.0, 4.0, 9.0, 0.04, 0.09, 0.16]
    (s,) = decode_can(fix2_frames(timestamp=stamp(7_000_000), status=3, ned_velocity=[3.0, -4.0, 0.5], covariance=cov,
                                  latitude_deg_1e8=4739770000, longitude_deg_1e8=854560000, height_msl_mm=488200))
    f16 = [float(np.float16(v)) for v in cov[3:]]
    assert s.vel_ned_m_s == (3.0, -4.0, 0.5) and s.vertical_velocity is True
    assert s.speed_accuracy_m_s == pytest.approx(math.sqrt(sum(f16) / 3))  # about 0.311 m/s
    assert (s.lat_deg, s.lon_deg, s.alt_m) == pytest.approx((47.3977, 8.5456, 488.2))
    assert s.t_ns == 7_000_000_000 and s.fix_type == 3 and s.source == SourceId("dronecan", 33, 0, 0)


def test_fix2_full_covariance_matrix_and_rtk_fixed():
    cov = [0.0] * 36
    cov[21], cov[28], cov[35] = 0.01, 0.01, 0.04  # the velocity block's diagonal of the 6x6 matrix
    (s,) = decode_can(fix2_frames(timestamp=stamp(7_000_000), status=3, mode=2, sub_mode=1, ned_velocity=[1.0, 0.0, 0.0],
                                  covariance=cov, latitude_deg_1e8=4739770000, longitude_deg_1e8=854560000))
    f16 = [float(np.float16(v)) for v in (0.01, 0.01, 0.04)]
    assert s.speed_accuracy_m_s == pytest.approx(math.sqrt(sum(f16) / 3)) and s.fix_type == 6


def test_fix2_without_covariance_or_fix():
    (s,) = decode_can(fix2_frames(timestamp=stamp(7_000_000), status=3, ned_velocity=[1.0, 0.0, 0.0],
                                  latitude_deg_1e8=4739770000, longitude_deg_1e8=854560000))
    assert s.speed_accuracy_m_s is None
    (s,) = decode_can(fix2_frames(timestamp=stamp(7_000_000), status=1))  # time only
    assert s.vel_ned_m_s is None and s.fix_type == 1 and s.lat_deg is None


def test_fix2_without_a_timestamp_is_placed_on_its_nodes_clock():
    decoder = DroneCanDecoder()
    raw = dronecan.TYPENAMES["uavcan.equipment.ahrs.RawIMU"](timestamp=stamp(5_000_000))
    imu = Transfer(payload=raw, source_node_id=33, transfer_id=0, transfer_priority=20).to_frames()
    decode_can([can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=1000.0) for f in imu], decoder)
    (s,) = decode_can(fix2_frames(rx_time=1000.5, status=3, ned_velocity=[1.0, 0.0, 0.0],
                                  latitude_deg_1e8=4739770000, longitude_deg_1e8=854560000), decoder)
    assert s.t_ns == 5_500_000_000  # node 33's clock is 995 s behind receive time


@pytest.mark.parametrize("message, accuracy", [("GPS_INPUT", 0.3), ("HIL_GPS", None)])  # HIL_GPS carries no accuracy
def test_mavlink_gnss_encoders_round_trip(message, accuracy):
    sample = GnssSample(5_000_000_000, 3, (3.0, -4.0, 0.5), True, accuracy, 47.3977, 8.5456, 488.2, False, SourceId("mavlink", 1, 1, 0))
    (s,) = MavlinkDecoder().feed(MavlinkEncoder(heartbeat=False).encode(sample, message))
    assert s.vel_ned_m_s == pytest.approx((3.0, -4.0, 0.5), abs=0.005) and s.vertical_velocity
    assert s.speed_accuracy_m_s == (None if accuracy is None else pytest.approx(accuracy))
    assert s.t_ns == sample.t_ns


def test_fix2_encoder_round_trip():
    sample = GnssSample(5_000_000_000, 6, (3.0, -4.0, 0.5), True, 0.3, 47.3977, 8.5456, 488.2, False, SourceId("dronecan", 7, 0, 0))
    (s,) = decode_can(encode_dronecan(sample, node_id=7, transfer_id=3))
    assert s.vel_ned_m_s == (3.0, -4.0, 0.5) and s.fix_type == 6
    assert s.speed_accuracy_m_s == pytest.approx(0.3, rel=2**-10)
    assert (s.lat_deg, s.lon_deg, s.alt_m) == pytest.approx((47.3977, 8.5456, 488.2))
