"""``bingham-fuser import``: real sensor logs (BROAD trials, PX4 ULogs, ArduPilot DataFlash logs) as the
MAVLink an autopilot would send.

Each IMU sample is packed as a MAVLink 2 HIGHRES_IMU frame (its ``id`` the IMU
instance, the magnetometer in it where the log has one for that message), the
autopilot's attitude as its attitude stream (PX4's EKF2 as
ATTITUDE_QUATERNION, ArduPilot's ATT as ATTITUDE), GNSS fixes as
:data:`GNSS_MESSAGE`; the bytes are decoded back by the
project's own :class:`drivers.mavlink_decode.MavlinkDecoder`, and the decoded
samples are recorded to an MCAP that ``bingham-fuser replay`` reads. The
reference attitude goes on ``/truth/pose`` (``McapRecorder.write_truth``):
for BROAD it is the optical motion-capture truth; for PX4 it is EKF2's
``vehicle_attitude``, for ArduPilot its ATT (a *reference*, not truth: the
MCAP metadata says so). Sender times: sample ``i`` of BROAD is stamped
``i / fs`` (fs = 285.714 Hz, exactly 3500 us); PX4 samples keep their ULog
``timestamp`` (us since boot), DataFlash records their ``TimeUS``/``TimeMS``.
Receive time = sender time + 1 ms (a fixed link latency, as in the simulator). Inputs and reference are
written in one pass, in log-time order (:func:`write_mcap`).

Frames and units (every conversion is a product with a fixed rotation; no
component is ever swapped by hand):

BROAD (Laidig et al., "BROAD - A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021, CC-BY-4.0)
    * ``imu_gyr`` rad/s, ``imu_acc`` m/s^2 and ``imu_mag`` uT in the IMU's own
      sensor frame S; ``opt_quat`` (w, x, y, z) rotates S into the ENU earth
      frame E (``v_E = q_ES v_S q_ES*``).
    * Body FRD frame B := S turned 180 degrees about its x axis (S is treated
      as x forward, y left, z up): ``Q_SB = (0, 1, 0, 0)``, and vectors are
      mapped with ``v_B = Q_BS v_S Q_BS*`` (``Q_BS = Q_SB*``). At rest, level,
      the accelerometer then reads about (0, 0, -9.81): gravity's reaction
      points up, which is -z in FRD.
    * World NED frame N: ``Q_NE`` = 180 degrees about (1, 1, 0)/sqrt(2) maps
      E (east) -> N y (east), E (north) -> N x, E (up) -> -N z.
    * Attitude: ``q_NB = Q_NE (x) q_ES (x) Q_SB`` (the inverse,
      ``q_ES = Q_NE* (x) q_NB (x) Q_SB*``, is :func:`broad_quat_from_ned`).
    * Magnetometer: uT -> gauss (1 G = 100 uT), ``mag_G = imu_mag * 0.01``;
      the fuser gates on the field's norm and dip, so the reference field
      must be the lab's, not the default: see *Reference field*.
    * Rows where ``opt_quat`` is NaN (markers lost) get no truth message.

PX4 ULog (``sensor_combined``, ``vehicle_attitude``)
    * PX4 already uses body FRD and world NED, gyro rad/s, accelerometer
      m/s^2, magnetometer gauss, quaternions (w, x, y, z) body -> world: the
      fixed rotations are identities and nothing is converted.
    * ``vehicle_attitude`` is EKF2's estimate; it is sent as
      ATTITUDE_QUATERNION (an autopilot's attitude stream) and also written
      on ``/truth/pose`` as the reference to compare with (metadata
      ``reference = EKF2``). EKF2's heading is relative to *true* north
      (it applies the declination), the fuser's to magnetic north unless its
      reference field says otherwise: the reference field below carries the
      declination EKF2 learned.

    * The magnetometer: ``sensor_combined.magnetometer_ga`` on older firmware; from PX4 1.10 on it is its own
      topic, ``vehicle_magnetometer`` (instance 0, the one EKF2 uses; ``magnetometer_ga`` gauss, body FRD,
      calibrated), each reading stamped with ``timestamp_sample`` and carried by the next ``sensor_combined``
      sample, as ArduPilot's by its next IMU message (:func:`mag_on_next_imu`).

    * GNSS, when the log has it (``vehicle_gps_position``, or ``sensor_gps`` on
      newer firmware; position as ``lat``/``lon``/``alt`` in 1e-7 degrees and mm,
      or ``latitude_deg``/``longitude_deg``/``altitude_msl_m`` on newer
      firmware): ``vel_n_m_s``, ``vel_e_m_s``, ``vel_d_m_s`` (NED, valid when
      ``vel_ned_valid`` and ``fix_type`` >= 2), ``s_variance_m_s`` (despite its
      name the one-sigma speed accuracy in m/s, as the message documents it),
      ``fix_type`` (PX4's values are MAVLink's GPS_FIX_TYPE), stamped with
      ``timestamp_sample`` where the message has it, else ``timestamp``.

ArduPilot DataFlash (``.bin``)
    See :mod:`fuser.dataflash`: already body FRD, world NED; IMU and MAG of
    every instance, GPS and the autopilot's ATT attitude, the log's own time.

GNSS samples travel as MAVLink like the rest (:data:`GNSS_MESSAGE`): a
GPS_INPUT with the receiver's NED velocity, vertical included, and its speed
accuracy.

Reference field
    The fuser wants ``mag_field_ned_gauss`` (north, east, down). For BROAD it
    is measured from the data itself, causally: the per-sample magnetometer
    norm and dip (against the accelerometer's down) averaged over the first
    ``field_rest_s`` seconds (every BROAD trial starts at rest); its horizontal part is
    put on magnetic north (declination 0: BROAD's ENU frame is the
    magnetometer's). For PX4 it is EKF2's own earth-field state
    (``estimator_status.states[16:19]``, gauss NED, median over the log) when
    the log has it, so declination is included; otherwise it is the World
    Magnetic Model's at the first 3-D fix when the log has GNSS, else (as in
    pyulog's sample.ulg, whose estimator logs no field state, whose
    declination parameter is 0 and which has no GNSS) it is measured at rest
    like BROAD's. For DataFlash it is the
    World Magnetic Model's (:mod:`core.earth_field`) at the first 3-D fix, on
    the fix's date (declination included, as ArduPilot's heading is from true
    north), else measured at rest. It is written to the MCAP metadata
    (``fuser`` record) and to a TOML file for ``replay --config``.
"""

from __future__ import annotations

import contextlib
import functools
import heapq
import io
import math
import os
import re
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence, TextIO

import numpy as np

from core import earth_field
from core import quaternion as quat
from drivers.mavlink_decode import MavlinkDecoder
from drivers.mavlink_encode import MavlinkEncoder, UnencodableSample
from drivers.samples import AttitudeSample, GnssSample, ImuSample, SourceId
from drivers.timebase import MAX_TIME_NS, NS_PER_MS, NS_PER_US
from drivers.validation import ACCEL_MAX_M_S2, MAG_MAX_GAUSS, MAG_MIN_FIELD_GAUSS
from fuser.config import MagSettings

__all__ = [
    "BROAD_ATTRIBUTION",
    "FORMATS",
    "GNSS_MESSAGE",
    "PX4_ATTRIBUTION",
    "Q_NE",
    "Q_SB",
    "ImportSummary",
    "ImuStream",
    "SensorData",
    "broad_quat_from_ned",
    "field_from_gnss",
    "field_from_rest",
    "in_cut",
    "import_log",
    "mag_on_next_imu",
    "read_broad",
    "read_px4",
    "write_mcap",
]

os.environ.setdefault("MAVLINK20", "1")

DEFAULT_FIELD_NED_GAUSS = MagSettings().fallback_field_ned_gauss
"""The reference field written for a log that gives none (the fuser's own fallback)."""
NO_FIELD_SOURCE = "none in the log: the default"


def rest_field_source(field_rest_s: float) -> str:
    """What a reference field measured by :func:`field_from_rest` is called in the metadata."""
    return f"mean of the first {field_rest_s:g} s at rest (norm, dip; declination 0)"


BROAD_ATTRIBUTION = (
    "BROAD dataset: D. Laidig, M. Caruso, A. Cereatti, T. Seel, 'BROAD - A Benchmark for Robust Inertial "
    "Orientation Estimation', Data 6(7):72, 2021, doi:10.3390/data6070072; github.com/dlaidig/broad; "
    "license CC-BY-4.0 (https://creativecommons.org/licenses/by/4.0/). Converted (frames, units, MAVLink) "
    "and cut by bingham-fuser import."
)
PX4_ATTRIBUTION = (
    "PX4 flight log sample.ulg from the pyulog project (github.com/PX4/pyulog, test/sample.ulg), "
    "BSD-3-Clause license. Converted to MAVLink and cut by bingham-fuser import."
)

S2 = math.sqrt(0.5)
Q_SB = np.array([0.0, 1.0, 0.0, 0.0])
"""Body FRD -> BROAD sensor frame: 180 degrees about x (self-inverse up to sign)."""
Q_BS = quat.conjugate(Q_SB)
Q_NE = np.array([0.0, S2, S2, 0.0])
"""World ENU -> world NED: 180 degrees about (1, 1, 0)/sqrt(2)."""
UT_TO_GAUSS = 0.01
LINK_LATENCY_NS = 1_000_000
GNSS_MESSAGE = "GPS_INPUT"
"""How imported GNSS fixes travel: GPS_INPUT carries the receiver's NED velocity (vertical included, which
GPS_RAW_INT's ground speed and course drop) and its speed accuracy, the whole of what the logs hold."""
MAVLINK_SOURCE = SourceId("mavlink", 1, 1, 0)


@dataclass
class ImuStream:
    """One IMU's samples: sender times (int64 ns), gyro (n, 3) rad/s, specific force (n, 3) m/s^2, body FRD,
    and the magnetometer (n, 3) gauss that each IMU message carries (NaN rows: none in that message)."""

    instance: int
    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None


@dataclass
class SensorData:
    """One log in the project's conventions: body FRD, world NED, SI units, magnetometer in gauss."""

    imus: list[ImuStream]  # one per IMU instance, the first is the primary
    ref_t_ns: np.ndarray  # reference attitude times
    ref_q: np.ndarray  # (m, 4) body FRD -> world NED, NaN rows where unknown
    reference: str  # "truth (...)" or "EKF2 (...)"
    attribution: str
    source: str
    mag_field_ned_gauss: tuple[float, float, float] | None
    """The reference field the log gives; None: it gives none (:func:`write_mcap` writes the default)."""
    field_source: str = rest_field_source(2.0)
    attitude_stream: bool = False  # also send ref_q as the autopilot's attitude messages
    attitude_message: str = "ATTITUDE_QUATERNION"  # PX4's; ArduPilot sends ATTITUDE
    gnss: list[GnssSample] = field(default_factory=list)  # fixes, in time order
    skipped: dict[str, int] = field(default_factory=dict)  # records not imported, by reason
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # e.g. BROAD's movement mask

    @property
    def t_ns(self) -> np.ndarray:
        """The primary IMU's sample times."""
        return self.imus[0].t_ns

    @property
    def gyro(self) -> np.ndarray:
        return self.imus[0].gyro

    @property
    def accel(self) -> np.ndarray:
        return self.imus[0].accel

    @property
    def mag(self) -> np.ndarray | None:
        return self.imus[0].mag


class EmptyCut(ValueError):
    """A reader's ``start_s`` and ``duration_s`` leave no IMU sample of a log whose IMU data lasts ``length_s`` (an empty
    import was written as an MCAP of nothing, with the fallback field printed as the one measured, exit 0)."""

    def __init__(self, length_s: float) -> None:
        super().__init__(f"the log holds {length_s:.1f} s of IMU data")
        self.length_s = length_s


@dataclass(frozen=True)
class ImportSummary:
    path: Path
    imu: int
    attitude: int
    truth: int
    decoder_stats: dict
    mag_field_ned_gauss: tuple[float, float, float]
    config_path: Path | None
    gnss: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def refused(self) -> dict[str, int]:
        """The samples the decoder refused on their way into the MCAP, by reason (its stats but the counts of what it
        took or ignored): left out of the import as much as ``skipped``."""
        from fuser.inputs import NOT_REFUSALS  # noqa: PLC0415 - fuser.inputs reads .tlogs: only for this

        return {k: v for k, v in sorted(self.decoder_stats.items()) if k not in NOT_REFUSALS and v}


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    return quat.rotate(np.broadcast_to(q, v.shape[:-1] + (4,)), v)


def broad_vectors_to_frd(v_s: np.ndarray) -> np.ndarray:
    """BROAD sensor-frame vectors -> body FRD: ``v_B = Q_BS v_S Q_BS*``."""
    return _rotate(Q_BS, np.asarray(v_s, dtype=float))


def broad_quat_to_ned(q_es: np.ndarray) -> np.ndarray:
    """BROAD ``opt_quat`` (sensor -> ENU) -> body FRD -> world NED: ``Q_NE (x) q_ES (x) Q_SB``."""
    q_es = np.asarray(q_es, dtype=float)
    return quat.multiply(quat.multiply(np.broadcast_to(Q_NE, q_es.shape), q_es), np.broadcast_to(Q_SB, q_es.shape))


def broad_quat_from_ned(q_nb: np.ndarray) -> np.ndarray:
    """Inverse of :func:`broad_quat_to_ned`: an estimate (FRD -> NED) as BROAD sensor -> ENU."""
    q_nb = np.asarray(q_nb, dtype=float)
    return quat.multiply(quat.multiply(np.broadcast_to(quat.conjugate(Q_NE), q_nb.shape), q_nb), np.broadcast_to(Q_BS, q_nb.shape))


def field_from_rest(accel: np.ndarray, mag: np.ndarray) -> tuple[float, float, float] | None:
    """Reference field (N, E, D gauss) from body-frame samples: mean norm and mean dip, declination 0; None
    without a usable sample.

    Norm and dip (angle below the horizontal, from the accelerometer's down)
    are computed per sample and then averaged, so slow rotation during the
    window does not bias them (a mean of vectors would). Only samples the
    drivers would accept count (finite, within ``drivers.validation``'s
    ranges, some specific force, a field a reference can be): one damaged
    record must not become the reference every heading is measured against.
    """
    a = np.asarray(accel, dtype=float).reshape(-1, 3)
    m = np.asarray(mag, dtype=float).reshape(-1, 3)
    with np.errstate(invalid="ignore"):
        usable = (np.all(np.abs(a) <= ACCEL_MAX_M_S2, axis=1) & np.all(np.abs(m) <= MAG_MAX_GAUSS, axis=1)
                  & (np.linalg.norm(a, axis=1) > 0.0) & (np.linalg.norm(m, axis=1) >= MAG_MIN_FIELD_GAUSS))
    if not np.any(usable):
        return None
    a, m = a[usable], m[usable]
    down = -a / np.linalg.norm(a, axis=1)[:, None]  # the accelerometer reads the reaction to gravity
    norms = np.linalg.norm(m, axis=1)
    dips = np.arcsin(np.clip(np.sum(m * down, axis=1) / norms, -1.0, 1.0))
    norm, dip = float(np.mean(norms)), float(np.mean(dips))
    return (norm * math.cos(dip), 0.0, norm * math.sin(dip))


def read_broad(path: str | Path, start_s: float = 0.0, duration_s: float | None = None, field_rest_s: float = 2.0) -> SensorData:
    """A BROAD trial (.hdf5) in the project's conventions; ``start_s``/``duration_s`` cut it."""
    import h5py

    with h5py.File(path, "r") as f:
        fs = float(f.attrs["sampling_rate"])
        gyr, acc, mag = (np.asarray(f[k], dtype=float) for k in ("imu_gyr", "imu_acc", "imu_mag"))
        q_es = np.asarray(f["opt_quat"], dtype=float)
        movement = np.asarray(f["movement"], dtype=bool)
    n = len(gyr)
    i0 = int(round(start_s * fs))
    i1 = n if duration_s is None else min(n, i0 + int(round(duration_s * fs)))
    if i1 <= i0:
        raise EmptyCut((n - 1) / fs)
    sl = slice(i0, i1)
    gyro, accel = broad_vectors_to_frd(gyr[sl]), broad_vectors_to_frd(acc[sl])
    mag_g = broad_vectors_to_frd(mag[sl]) * UT_TO_GAUSS
    rest = max(1, int(field_rest_s * fs))
    t_ns = np.round(np.arange(i0, i1) * (1e9 / fs)).astype(np.int64)
    # time_usec travels in microseconds: stamp on whole microseconds (1/fs is exactly 3500 us)
    t_ns = (t_ns // 1000) * 1000
    return SensorData(
        imus=[ImuStream(0, t_ns, gyro, accel, mag_g)],
        ref_t_ns=t_ns.copy(),
        ref_q=broad_quat_to_ned(q_es[sl]),
        reference="truth (BROAD opt_quat, optical motion capture)",
        attribution=BROAD_ATTRIBUTION,
        source=f"BROAD trial {Path(path).stem}, samples {i0}..{i1} of {n} at {fs:.3f} Hz",
        mag_field_ned_gauss=field_from_rest(accel[:rest], mag_g[:rest]),
        field_source=rest_field_source(field_rest_s),
        extra={"movement": movement[sl], "index": np.arange(i0, i1), "q_es": q_es[sl]},
    )


def _ulog_vec(d: dict, name: str) -> np.ndarray:
    return np.column_stack([np.asarray(d[f"{name}[{i}]"], dtype=float) for i in range(3)])


def in_cut(t: np.ndarray, t0: int, t1: int | None) -> np.ndarray:
    """Which times ``t`` lie in the cut ``[t0, t1)`` (``t1`` None: to the end)."""
    return (t >= t0) & (t < t1) if t1 is not None else t >= t0


def mag_on_next_imu(imu_t_ns: np.ndarray, mag_t_ns: np.ndarray, mag_gauss: np.ndarray) -> tuple[np.ndarray, int]:
    """(n, 3) gauss for n IMU samples: each magnetometer reading on the first IMU sample at or after its time (the
    latest one when several fall between two IMU samples), NaN rows elsewhere, as an autopilot's IMU message carries
    the latest compass reading; and how many readings came after the last IMU sample (none carries them)."""
    out = np.full((len(imu_t_ns), 3), np.nan)
    at = np.searchsorted(imu_t_ns, mag_t_ns)
    inside = at < len(imu_t_ns)
    out[at[inside]] = np.asarray(mag_gauss, dtype=float)[inside]  # later readings overwrite earlier ones
    return out, int(np.sum(~inside))


def field_from_gnss(fixes: list[GnssSample], unix_time_s: float | None) -> tuple[float, float, float] | None:
    """The World Magnetic Model field at the first 3-D fix with a position the model takes, on the given date;
    None without one (or for a date outside the model's years: a damaged log's)."""
    if unix_time_s is None:
        return None
    for fix in fixes:
        if fix.fix_type >= 3 and fix.lat_deg is not None:
            try:
                return earth_field.field_ned_gauss(fix.lat_deg, fix.lon_deg, fix.alt_m, earth_field.decimal_year(unix_time_s))  # type: ignore[arg-type]
            except ValueError:  # a position or date the model refuses: a damaged record, the next fix may do
                continue
    return None


def _sample_stamp(d: dict) -> str:
    """The field that stamps a topic's samples: ``timestamp_sample`` (when the sensor measured) where the topic has
    it and it is set, else ``timestamp`` (when it was published)."""
    return "timestamp_sample" if "timestamp_sample" in d and np.all(np.asarray(d["timestamp_sample"]) > 0) else "timestamp"


def _px4_magnetometer(topics: dict, imu_t_ns: np.ndarray, t0_us: int, t1_us: int | None, skipped: Counter) -> np.ndarray | None:
    """``vehicle_magnetometer`` (PX4 1.10 on, whose ``sensor_combined`` has no magnetometer) within the cut, each reading
    on the next IMU sample (:func:`mag_on_next_imu`; those after the last are counted as ``mag_after_last_imu``);
    None without the topic."""
    d = topics.get("vehicle_magnetometer")
    if d is None:
        return None
    t_us, valid = _ulog_times_us(d, "vehicle_magnetometer", skipped, _sample_stamp(d))
    inside = valid & in_cut(t_us, t0_us, t1_us)
    mag, late = mag_on_next_imu(imu_t_ns, t_us[inside] * 1000, _ulog_vec(d, "magnetometer_ga")[inside])
    if late:
        skipped["mag_after_last_imu"] += late
    return mag


def _px4_gnss(topics: dict, t0_us: int, t1_us: int | None, skipped: Counter) -> tuple[list[GnssSample], float | None]:
    """GnssSamples of ``vehicle_gps_position`` (else ``sensor_gps``) within the cut, and the UTC time of
    the first 3-D fix that has one (seconds since 1970), for the magnetic model's date; a fix whose time is not
    one is counted in ``skipped``."""
    name = "vehicle_gps_position" if "vehicle_gps_position" in topics else "sensor_gps"
    d = topics.get(name)
    if d is None:
        return [], None
    t_us, valid = _ulog_times_us(d, name, skipped, _sample_stamp(d))
    if "latitude_deg" in d:  # newer firmware
        lat, lon, alt = (np.asarray(d[k], dtype=float) for k in ("latitude_deg", "longitude_deg", "altitude_msl_m"))
    else:  # 1e-7 degrees and millimetres
        lat, lon, alt = np.asarray(d["lat"]) * 1e-7, np.asarray(d["lon"]) * 1e-7, np.asarray(d["alt"]) * 1e-3
    fix = np.asarray(d["fix_type"], dtype=int)
    vel_valid = np.asarray(d["vel_ned_valid"], dtype=bool) if "vel_ned_valid" in d else np.ones(len(fix), dtype=bool)
    vel = np.column_stack([np.asarray(d[f"vel_{a}_m_s"], dtype=float) for a in "ned"])
    accuracy = np.asarray(d["s_variance_m_s"], dtype=float)
    utc = np.asarray(d.get("time_utc_usec", np.zeros(len(fix))), dtype=np.int64)
    fixes, first_utc = [], None
    for i in np.flatnonzero(valid & in_cut(t_us, t0_us, t1_us)):
        has_position = fix[i] >= 2
        fixes.append(GnssSample(
            int(t_us[i]) * 1000, int(fix[i]),
            tuple(float(v) for v in vel[i]) if vel_valid[i] and fix[i] >= 2 else None,  # type: ignore[arg-type]
            bool(fix[i] >= 3), float(accuracy[i]) if accuracy[i] > 0 else None,
            float(lat[i]) if has_position else None, float(lon[i]) if has_position else None,
            float(alt[i]) if has_position else None, False, MAVLINK_SOURCE,
        ))
        if first_utc is None and fix[i] >= 3 and utc[i] > 0:
            first_utc = utc[i] * 1e-6
    return fixes, first_utc


ULOG_FILE_HEADER_BYTES = 16
"""A ULog's file header (magic, version, start time): its messages follow."""
ULOG_MESSAGE_HEADER = struct.Struct("<HB")
"""Every ULog message's header: payload size (bytes), message type."""
ULOG_MESSAGE_TYPES = frozenset(b"BFIMPQARDLCSO")
"""The message types of the ULog format (flag bits, format, info, info multiple, parameter, parameter default,
add and remove subscription, data, logging, tagged logging, sync, dropout)."""


def ulog_incomplete_tail_bytes(path: str | Path, appended_offsets: Sequence[int] = ()) -> int | None:
    """How many bytes at the end of a ULog do not make a whole message: 0 for a log that ends where its last
    message does; for a log cut short (power lost while it was written, a download that stopped), the last
    message's bytes that are there. pyulog stops at such a message in silence. Walks the messages' own sizes
    from a message boundary: the last of the file's appended-data offsets (its flag bits) that lies within
    the file, else the first message after the file header. None when the walk meets a type that is no ULog
    message's: damage has broken the framing there, and where the file ends inside a message cannot be told."""
    with open(path, "rb") as f:
        data = f.read()
    at = max((offset for offset in appended_offsets if ULOG_FILE_HEADER_BYTES <= offset <= len(data)), default=ULOG_FILE_HEADER_BYTES)
    while at + ULOG_MESSAGE_HEADER.size <= len(data):
        size, kind = ULOG_MESSAGE_HEADER.unpack_from(data, at)
        if kind not in ULOG_MESSAGE_TYPES:
            return None
        end = at + ULOG_MESSAGE_HEADER.size + size
        if end > len(data):
            break
        at = end
    return len(data) - at


def _ulog(path: str | Path, topics: list[str]) -> tuple[Any, Counter]:
    """pyulog's reading of ``topics`` and what it reported (it reports damage with print(), silenced here):
    ``corrupt_data`` 1 if it found corrupt data (and skipped to the next sync), ``unknown_message_id`` the ids
    of data it found no subscription for (it says so once per id, not per record);
    ``incomplete_tail_bytes`` (:func:`ulog_incomplete_tail_bytes`; not counted where damage hides it); and the
    logger's own dropouts (``logger_dropouts``, ``logger_dropout_ms``: data PX4 lost before it was written, where its
    log buffer overflowed)."""
    from pyulog import ULog

    chatter = io.StringIO()
    with contextlib.redirect_stdout(chatter):
        ulog = ULog(str(path), topics)
    text = chatter.getvalue()
    appended = ulog._appended_offsets if ulog.has_data_appended else []  # pyulog keeps the offsets private
    skipped = Counter({"corrupt_data": int(bool(ulog.file_corruption or "corruption detected" in text)),
                       "unknown_message_id": len(set(re.findall(r"no subscription found for message id (\d+)", text))),
                       "incomplete_tail_bytes": ulog_incomplete_tail_bytes(path, appended) or 0,
                       "logger_dropouts": len(ulog.dropouts),
                       "logger_dropout_ms": sum(d.duration for d in ulog.dropouts)})
    return ulog, +skipped


def _ulog_times_us(d: dict, topic: str, skipped: Counter, field: str = "timestamp") -> tuple[np.ndarray, np.ndarray]:
    """A topic's times (``field``, us since boot) and which of them can be times at all: in [0, MAX_TIME_NS) as
    ns (a damaged record's may be anything; the others counted as ``time_out_of_range_<topic>``). A damaged time
    inside that range is placed where it says: the decoder's time checks take it from there."""
    t_us = np.asarray(d[field]).astype(np.int64)  # uint64: a damaged one beyond 2^63 turns negative
    valid = (t_us >= 0) & (t_us < MAX_TIME_NS // NS_PER_US)
    if not np.all(valid):
        skipped[f"time_out_of_range_{topic}"] += int(np.count_nonzero(~valid))
    return t_us, valid


def read_px4(path: str | Path, start_s: float = 0.0, duration_s: float | None = None, field_rest_s: float = 2.0) -> SensorData:
    """A PX4 ULog's ``sensor_combined``, its magnetometer (in ``sensor_combined`` on older firmware, else
    ``vehicle_magnetometer``), ``vehicle_attitude`` and GNSS (already FRD/NED, SI, gauss)."""
    ulog, skipped = _ulog(path, ["sensor_combined", "vehicle_attitude", "estimator_status", "vehicle_gps_position", "sensor_gps",
                                 "vehicle_magnetometer"])
    topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    missing = [name for name in ("sensor_combined", "vehicle_attitude") if name not in topics]
    if missing:
        damage = f" (pyulog reported {dict(skipped)})" if skipped else ""
        raise ValueError(f"{Path(path).name} has no {' or '.join(missing)} data{damage}")
    sc, va = topics["sensor_combined"], topics["vehicle_attitude"]
    t_us, valid = _ulog_times_us(sc, "sensor_combined", skipped)
    if not np.any(valid):
        raise ValueError(f"{Path(path).name}: no sensor_combined record has a time since boot")
    t0 = int(t_us[valid].min() + start_s * 1e6)  # the earliest: a damaged first record's time may lie ahead
    t1 = None if duration_s is None else t0 + int(duration_s * 1e6)
    keep = valid & in_cut(t_us, t0, t1)
    if not np.any(keep):
        raise EmptyCut(float(t_us[valid].max() - t_us[valid].min()) / 1e6)
    gyro = _ulog_vec(sc, "gyro_rad")[keep]
    accel = _ulog_vec(sc, "accelerometer_m_s2")[keep]
    mag = _ulog_vec(sc, "magnetometer_ga")[keep] if "magnetometer_ga[0]" in sc else _px4_magnetometer(topics, t_us[keep] * 1000, t0, t1, skipped)
    va_t, va_valid = _ulog_times_us(va, "vehicle_attitude", skipped)
    va_keep = va_valid & in_cut(va_t, t0, t1)
    ref_q = np.column_stack([np.asarray(va[f"q[{i}]"], dtype=float) for i in range(4)])[va_keep]
    gnss, first_utc = _px4_gnss(topics, t0, t1, skipped)
    mag_field, field_source = None, "EKF2 earth-field state (estimator_status.states[16:19], median)"
    if "estimator_status" in topics and "states[18]" in topics["estimator_status"]:
        es = topics["estimator_status"]
        states = np.column_stack([np.asarray(es[f"states[{i}]"], dtype=float) for i in (16, 17, 18)])
        states = states[np.linalg.norm(states, axis=1) > 0.05]  # before EKF2 initialises its field the state is zero
        if len(states):
            mag_field = tuple(float(v) for v in np.median(states, axis=0))
    if mag_field is None and (mag_field := field_from_gnss(gnss, first_utc)) is not None:
        field_source = "World Magnetic Model at the first 3-D fix (declination included)"
    if mag_field is None and mag is not None:
        rest = t_us[keep] < t0 + field_rest_s * 1e6
        mag_field = field_from_rest(accel[rest], mag[rest])
        field_source = rest_field_source(field_rest_s)
    return SensorData(
        imus=[ImuStream(0, t_us[keep] * 1000, gyro, accel, mag)],
        ref_t_ns=va_t[va_keep] * 1000,
        ref_q=ref_q,
        reference="EKF2 (PX4 vehicle_attitude: the autopilot's estimate, NOT ground truth)",
        attribution=PX4_ATTRIBUTION,
        source=f"PX4 ULog {Path(path).name}, sensor_combined from {start_s:g} s" + (f" for {duration_s:g} s" if duration_s else ""),
        mag_field_ned_gauss=mag_field,
        attitude_stream=True,
        field_source=field_source,
        gnss=gnss,
        skipped=dict(skipped),
    )


_IMU, _ATTITUDE, _GNSS = 0, 1, 2


def _events(data: SensorData) -> list[tuple[int, int, int, int]]:
    """(sender time, kind, IMU stream, index) of every message, in sender-time order (IMUs first on ties)."""
    events = [(int(t), _IMU, j, i) for j, imu in enumerate(data.imus) for i, t in enumerate(imu.t_ns.tolist())]
    if data.attitude_stream:
        events += [(int(t), _ATTITUDE, 0, i) for i, t in enumerate(data.ref_t_ns.tolist())]
    events += [(g.t_ns, _GNSS, 0, i) for i, g in enumerate(data.gnss)]
    return sorted(events)


def _is_rotation(q: np.ndarray) -> bool:
    """A quaternion that normalises to a rotation (not zeros, not NaN or infinite: a damaged record's)."""
    return 0.0 < float(np.linalg.norm(q)) < math.inf


def _message(data: SensorData, kind: int) -> str:
    """The MAVLink message an event of ``kind`` travels as."""
    return "HIGHRES_IMU" if kind == _IMU else data.attitude_message if kind == _ATTITUDE else GNSS_MESSAGE


def _sample(data: SensorData, kind: int, stream: int, i: int, t_ns: int) -> object:
    """The sample of one event; UnencodableSample for an attitude that is not a rotation (a damaged record's)."""
    if kind == _IMU:
        imu = data.imus[stream]
        mag = None if imu.mag is None or np.isnan(imu.mag[i, 0]) else tuple(float(v) for v in imu.mag[i])
        source = SourceId("mavlink", 1, 1, imu.instance)
        return ImuSample(t_ns, tuple(float(v) for v in imu.gyro[i]), tuple(float(v) for v in imu.accel[i]), mag, source)  # type: ignore[arg-type]
    if kind == _ATTITUDE:
        q = data.ref_q[i]
        if not _is_rotation(q):
            raise UnencodableSample(f"attitude at {t_ns} ns is not a rotation: {q.tolist()}")
        return AttitudeSample(t_ns, tuple(float(v) for v in quat.normalize(q)), MAVLINK_SOURCE)  # type: ignore[arg-type]
    return data.gnss[i]


_INPUT, _TRUTH = 0, 1
STAMP_RESOLUTION_NS = NS_PER_MS
"""The coarsest time a message the import sends carries: ATTITUDE(_QUATERNION)'s ``time_boot_ms`` (HIGHRES_IMU and
GPS_INPUT carry microseconds). A decoded sample's time is its event's cut down to it, so at most this much earlier."""


def _decoded(data: SensorData, events: Iterable[tuple[int, int, int, int]], encoder: MavlinkEncoder, decoder: MavlinkDecoder,
             skipped: Counter) -> Iterator[tuple[int, int, int, object]]:
    """Every event encoded as MAVLink and decoded back, as ``(receive time, _INPUT, n, sample)`` in receive-time order.

    The receive time is the decoded sample's time plus the link latency, and the decoded time is the sender's
    cut to what its message carries (an attitude's milliseconds): up to :data:`STAMP_RESOLUTION_NS` before
    messages sent ahead of it. So each is held until no later event can be received before it, never longer
    than that: a millisecond of messages, not the log. ``skipped`` counts the events that cannot be encoded.
    """
    held: list[tuple[int, int, int, object]] = []
    n = 0
    for t_ns, kind, stream, i in events:
        while held and held[0][0] <= t_ns + LINK_LATENCY_NS - STAMP_RESOLUTION_NS:  # no sample of this event or a later one goes before it
            yield heapq.heappop(held)
        message = _message(data, kind)
        try:
            frame = encoder.encode(_sample(data, kind, stream, i, t_ns), message)  # type: ignore[arg-type]
        except UnencodableSample:  # a damaged record's time or value: counted, the rest goes on
            skipped[f"out_of_range_{message}"] += 1
            continue
        for sample in decoder.feed(frame):
            heapq.heappush(held, (sample.t_ns + LINK_LATENCY_NS, _INPUT, n, sample))
            n += 1
    while held:
        yield heapq.heappop(held)


def _truth(data: SensorData) -> Iterator[tuple[int, int, int, tuple[float, ...]]]:
    """The reference attitudes as ``(time, _TRUTH, index, q)`` in time order (a damaged log's out of order are put in
    place), but where unknown (NaN rows) or damaged."""
    for i in np.argsort(data.ref_t_ns, kind="stable").tolist():
        q = data.ref_q[i]
        if _is_rotation(q):
            yield int(data.ref_t_ns[i]), _TRUTH, i, tuple(float(v) for v in quat.normalize(q))


def _listed(counts: dict[str, int]) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(counts.items()))


def write_mcap(data: SensorData, out: str | Path, config_path: str | Path | None = None, progress: TextIO | None = None) -> ImportSummary:
    """Encode ``data`` as MAVLink bytes, decode them with the project's driver, record MCAP (+ reference).

    ``progress``: where to draw a progress bar (only if it is a terminal).
    """
    from fuser.errors import FuserError, os_reason
    from fuser.progress import progress_bar
    from fuser.record import McapRecorder, RecordWriteError

    out = Path(out)
    encoder = MavlinkEncoder(system=1, component=1)
    decoder = MavlinkDecoder()
    skipped = Counter(data.skipped)
    if data.mag_field_ned_gauss is None:
        field_ned, field_source = DEFAULT_FIELD_NED_GAUSS, NO_FIELD_SOURCE
    else:
        field_ned, field_source = tuple(round(float(v), 6) for v in data.mag_field_ned_gauss), data.field_source
        try:  # the reference must be one the configuration takes (a damaged log's EKF2 state or readings may not be)
            MagSettings(field_ned_gauss=field_ned)  # type: ignore[arg-type]
        except ValueError:
            skipped["field_out_of_range"] += 1
            field_ned, field_source = DEFAULT_FIELD_NED_GAUSS, f"{NO_FIELD_SOURCE} ({field_source}: {list(field_ned)} is not a field)"
    metadata = {
        "source": data.source,
        "attribution": data.attribution,
        "reference": data.reference,
        "frames": "inputs body FRD; /truth/pose body FRD -> world NED, (w, x, y, z); see fuser/importers.py",
        "mag_field_ned_gauss": ",".join(f"{v:.6f}" for v in field_ned),
        "mag_field_source": field_source,
    }
    if skipped:
        metadata["skipped"] = _listed(skipped)
    skipped_before_encoding = Counter(skipped)
    counts = {ImuSample: 0, AttitudeSample: 0, GnssSample: 0}
    truth = 0
    try:
        with McapRecorder(out, metadata=metadata, stop_on_write_error=True) as rec:
            events = _events(data)
            decoded = _decoded(data, progress_bar(events, len(events), "import", " messages", progress), encoder, decoder, skipped)
            for log_ns, what, _, record in heapq.merge(decoded, _truth(data)):  # one stream in log-time order: inputs first on ties
                if what == _INPUT:
                    rec.write_sample(record, log_ns)  # type: ignore[arg-type]
                    counts[type(record)] += 1
                else:
                    rec.write_truth(log_ns, record)  # type: ignore[arg-type]
                    truth += 1
            if skipped != skipped_before_encoding:  # records the encoding left out too: the metadata again, complete (the last wins)
                rec.add_metadata("bingham_fuser", metadata | {"skipped": _listed(skipped)})
    except RecordWriteError as e:  # a full disk: an incomplete import is no import
        out.unlink(missing_ok=True)
        raise FuserError(f"cannot write {out}: {e.reason}; nothing was kept") from e
    cfg = None
    if config_path is not None:
        cfg = Path(config_path)
        try:
            cfg.write_text(
                f"# reference field for {out.name}, measured by bingham-fuser import (see fuser/importers.py)\n"
                f"[fuser.mag]\nfield_ned_gauss = [{field_ned[0]}, {field_ned[1]}, {field_ned[2]}]\n"
            )
        except OSError as e:  # a full disk: the MCAP is whole, its settings file is not
            cfg.unlink(missing_ok=True)
            raise FuserError(f"cannot write {cfg}: {os_reason(e)}; {out} was written, its reference field is "
                             f"{list(field_ned)} (mag_field_ned_gauss in its metadata)") from e
    return ImportSummary(out, counts[ImuSample], counts[AttitudeSample], truth, dict(decoder.stats), field_ned, cfg,  # type: ignore[arg-type]
                         counts[GnssSample], dict(skipped))


FORMATS = {"broad": "a BROAD trial (.hdf5)", "px4": "a PX4 ULog (.ulg)", "dataflash": "an ArduPilot DataFlash log (.bin)"}
SUFFIXES = {".hdf5": "broad", ".h5": "broad", ".ulg": "px4", ".bin": "dataflash"}
"""The file name endings each format is told by (any case)."""
READER_PACKAGES = {"broad": "h5py", "px4": "pyulog"}
"""The optional package (extra ``import``) each format's reader needs; DataFlash's, pymavlink, is a core dependency."""


def detect_format(path: str | Path) -> str:
    fmt = SUFFIXES.get(Path(path).suffix.lower())
    if fmt is None:
        raise ValueError(f"cannot tell the format of {path}: expected {', '.join(FORMATS.values())}")
    return fmt


def is_importable(path: str | Path) -> bool:
    """Whether ``path`` is named as a log :func:`read_sensor_log` reads (not an MCAP or a .tlog)."""
    return Path(path).suffix.lower() in SUFFIXES


def read_sensor_log(path: str | Path, fmt: str | None = None, start_s: float = 0.0, duration_s: float | None = None,
                    progress: TextIO | None = None) -> SensorData:
    """A BROAD trial, PX4 ULog or DataFlash log read by its format's reader (``fmt``: from the name if None), every
    way it can fail one line for the user: :class:`~fuser.errors.UsageError` for a name no format has or a reader
    package that is not installed, :class:`~fuser.errors.NotALogError` for a file the reader refuses. ``progress``:
    where to draw a bar while a DataFlash log is read (h5py and pyulog read a file whole, without one)."""
    from fuser.dataflash import read_dataflash
    from fuser.errors import NotALogError, UsageError, require_package

    try:
        fmt = fmt or detect_format(path)
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    if fmt in READER_PACKAGES:
        require_package(READER_PACKAGES[fmt], "import", f"reading {fmt} logs")
    reader = {"broad": read_broad, "px4": read_px4, "dataflash": functools.partial(read_dataflash, progress=progress)}[fmt]
    try:
        return reader(path, start_s, duration_s)
    except EmptyCut as exc:  # the user's window, not the file: a usage error
        window = f"from --start {start_s:g} s" + (f" for --duration {duration_s:g} s" if duration_s is not None else "")
        raise UsageError(f"nothing in {path} {window}: {exc}") from exc
    except Exception as exc:  # noqa: BLE001 - h5py, pyulog and DFReader raise anything on a file that is not theirs
        raise NotALogError(f"cannot read {path} as a {fmt} log: {type(exc).__name__}: {exc}") from exc


def import_log(
    path: str | Path,
    out: str | Path,
    fmt: str | None = None,
    start_s: float = 0.0,
    duration_s: float | None = None,
    config_path: str | Path | None = None,
    progress: TextIO | None = None,
) -> ImportSummary:
    """Read a BROAD trial, PX4 ULog or ArduPilot DataFlash log and write the MCAP ``out`` (and the TOML ``config_path``);
    failures as :func:`read_sensor_log`'s."""
    return write_mcap(read_sensor_log(path, fmt, start_s, duration_s, progress), out, config_path, progress)
