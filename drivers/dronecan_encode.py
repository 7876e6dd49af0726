"""Samples to DroneCAN frames (python-can ``Message``s), with the ``dronecan`` codec."""

from __future__ import annotations

import can
from dronecan.transport import Transfer

from .dronecan_decode import FIX2, FIX2_MODE_DGPS, FIX2_MODE_RTK, FIX2_SUB_MODE_RTK_FIXED, MAG_FIELD, RAW_IMU, SOLUTION, data_type
from .samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample
from .timebase import NS_PER_US

DEFAULT_PRIORITY = 16
_TIMESTAMP = data_type("uavcan.Timestamp")
_FIX2_STATUS_MODE = {0: (0, 0, 0), 1: (0, 0, 0), 2: (2, 0, 0), 3: (3, 0, 0), 4: (3, FIX2_MODE_DGPS, 0),
                     5: (3, FIX2_MODE_RTK, 0), 6: (3, FIX2_MODE_RTK, FIX2_SUB_MODE_RTK_FIXED)}
"""MAVLink GPS_FIX_TYPE to Fix2 (status, mode, sub_mode)."""


def _fix2(sample: GnssSample):  # type: ignore[no-untyped-def]
    """Fix2 of a GNSS sample; the speed accuracy becomes three equal velocity variances, position variances NaN (unknown)."""
    status, mode, sub_mode = _FIX2_STATUS_MODE[sample.fix_type]
    nan = float("nan")
    acc = sample.speed_accuracy_m_s
    return data_type(FIX2)(
        timestamp=_TIMESTAMP(usec=sample.t_ns // NS_PER_US),
        latitude_deg_1e8=round((sample.lat_deg or 0.0) * 1e8),
        longitude_deg_1e8=round((sample.lon_deg or 0.0) * 1e8),
        height_msl_mm=round((sample.alt_m or 0.0) * 1e3),
        ned_velocity=list(sample.vel_ned_m_s or (0.0, 0.0, 0.0)),
        status=status, mode=mode, sub_mode=sub_mode,
        covariance=[] if acc is None else [nan, nan, nan, acc * acc, acc * acc, acc * acc],
    )


def _payloads(sample: Sample) -> list:  # type: ignore[type-arg]
    """The DSDL messages that carry ``sample`` (an IMU sample with a magnetometer needs two)."""
    if isinstance(sample, ImuSample):
        raw = data_type(RAW_IMU)(
            timestamp=_TIMESTAMP(usec=sample.t_ns // NS_PER_US),
            integration_interval=-1.0,  # only the latest point samples are valid
            rate_gyro_latest=list(sample.gyro_rad_s),
            accelerometer_latest=list(sample.accel_m_s2),
        )
        if sample.mag_gauss is None:
            return [raw]
        return [raw, data_type(MAG_FIELD)(sensor_id=sample.source.instance, magnetic_field_ga=list(sample.mag_gauss))]
    if isinstance(sample, MagSample):
        return [data_type(MAG_FIELD)(sensor_id=sample.source.instance, magnetic_field_ga=list(sample.mag_gauss))]
    if isinstance(sample, AttitudeSample):
        w, x, y, z = sample.q_wxyz
        return [data_type(SOLUTION)(timestamp=_TIMESTAMP(usec=sample.t_ns // NS_PER_US), orientation_xyzw=[x, y, z, w])]
    if isinstance(sample, GnssSample):
        return [_fix2(sample)]
    raise TypeError(f"cannot encode {type(sample).__name__} as DroneCAN")


def encode_dronecan(
    sample: Sample, node_id: int, transfer_id: int, priority: int = DEFAULT_PRIORITY
) -> list[can.Message]:
    """Extended-id CAN frames of ``sample`` sent by ``node_id``, stamped with the sample time as receive time.

    IMU samples become a RawIMU transfer (latest samples, no integrals),
    followed by a MagneticFieldStrength2 transfer when they carry a
    magnetometer; attitude becomes a Solution transfer (orientation only), GNSS a Fix2.
    """
    frames = []
    for payload in _payloads(sample):
        transfer = Transfer(
            payload=payload, source_node_id=node_id, transfer_id=transfer_id % 32, transfer_priority=priority
        )
        frames += [
            can.Message(arbitration_id=f.message_id, data=f.bytes, is_extended_id=True, timestamp=sample.t_ns / 1e9)
            for f in transfer.to_frames()
        ]
    return frames
