"""ArduPilot DataFlash logs (``.bin``) for ``bingham-fuser import``, read with pymavlink's ``DFReader_binary``.

Message and field units as ArduPilot's log documentation and its
LogStructure.h give them; DFReader applies the format characters' scale
(``c``/``C``/``e``/``E`` x0.01, ``L`` x1e-7).

* Time: the log's own, microseconds since boot (``TimeUS``, firmware from
  2015 on) or milliseconds since boot (``TimeMS``, older logs; an old GPS
  message's ``TimeMS`` is the GPS time of week, its boot time is ``T``).
* IMU: ``IMU``, ``IMU2``, ``IMU3`` (instances 0, 1, 2) or, on newer
  firmware, one ``IMU`` message with the instance in ``I``. ``GyrX..Z``
  rad/s and ``AccX..Z`` m/s^2 (specific force), body FRD (ArduPilot's body
  frame: x forward, y right, z down; level at rest AccZ reads about -9.8).
  Samples whose ``GH``/``AH`` health flag is 0 are skipped and counted.
* MAG: ``MAG``, ``MAG2``, ``MAG3`` or ``MAG`` with ``I``; ``MagX..Z`` in
  milligauss, body FRD, **with the offsets already applied**: ArduPilot
  logs the corrected field (``AP_Compass_Backend::correct_field`` adds
  ``OfsX..`` and the motor compensation ``MOX..``/``MOfsX..`` and applies
  the soft-iron matrix before the field is logged), so the logged offsets
  are information and are not added again. Unhealthy samples (``Health``
  0) are skipped. Each magnetometer sample rides with the next IMU message
  of the same instance (as an autopilot's RAW_IMU/SCALED_IMU2/3 carry the
  latest compass reading), so it arrives up to one IMU period late; a
  magnetometer without an IMU of its instance is skipped and counted.
* GPS (instance 0: ``GPS``, or ``GPS`` with ``I`` = 0): ``Status``
  (ArduPilot's GPS_Status, the same numbers as MAVLink's GPS_FIX_TYPE),
  ``Lat``/``Lng`` degrees, ``Alt`` metres above mean sea level, ``Spd``
  ground speed m/s, ``GCrs`` course over ground in degrees, ``VZ`` vertical
  speed m/s positive *down* (ArduPilot logs ``velocity.z`` of its NED
  velocity): ``v_NED = (Spd cos GCrs, Spd sin GCrs, VZ)``; GPS week and
  time of week (``GWk``/``GMS``, old logs ``Week``/``TimeMS``) give the
  date. ``GPA.SAcc`` (m/s), where logged, is the speed accuracy. A second
  receiver (``GPS2``, ``I`` = 1) is counted, not imported.
* ATT: ``Roll``, ``Pitch``, ``Yaw`` in degrees (Euler 3-2-1 of body FRD in
  NED, yaw from true north): the autopilot's estimate (DCM or the EKF that
  ``AEKF``, or the ``AHRS_EKF_TYPE`` parameter, names). It goes on
  ``/truth/pose`` as the reference (metadata ``reference`` says whose, and
  that it is NOT ground truth) and is sent as ArduPilot's ATTITUDE stream.
* Corrupt bytes between records (SD-card logs have them) are skipped by
  DFReader and counted; the bytes after the last whole record, which
  DFReader passes over in silence, are counted as ``incomplete_tail_bytes``
  (a log cut short: power lost while it was written, a download that
  stopped; or the garbage some old logs end with); a record whose layout lacks a field the import
  needs (the earliest GPS layout has no boot time ``T``) is counted as
  ``unreadable_<name>``; a GPS layout without ``VZ`` gives no vertical
  velocity. A record whose time is not a time since boot
  (``drivers.timebase.MAX_TIME_NS``: a damaged one) is counted as
  ``time_out_of_range_<name>``, and a value MAVLink cannot carry as
  ``out_of_range_<message>`` (:func:`fuser.importers.write_mcap`).
* Boots: ``TimeUS`` is the time since boot, so a file that holds two boots (logs joined, a board that
  rebooted while its log went on) has a clock that starts again. Imported in time order, the boots would
  be interleaved into one flight that never was: the import takes the boot with the most IMU records
  (the first on ties) and counts the others (``other_boots``) and their records (``other_boot_records``).
  A restart is a step back in time that the IMU records after it confirm (:data:`RESTART_WINDOW`); one
  damaged time is not one.

The result is a :class:`fuser.importers.SensorData`, written to MCAP by
:func:`fuser.importers.write_mcap` exactly as a PX4 log is: every sample
through MAVLink and the project's decoder, the reference on ``/truth/pose``.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
from collections import Counter, defaultdict
from pathlib import Path
from typing import TextIO

import numpy as np

from drivers.euler import quaternion_from_euler
from drivers.samples import GnssSample
from drivers.timebase import MAX_TIME_NS
from fuser.progress import progress_bar

from .importers import (MAVLINK_SOURCE, EmptyCut, ImuStream, SensorData, field_from_gnss, field_from_rest, in_cut, mag_on_next_imu,
                        rest_field_source)

__all__ = ["read_dataflash"]

MGAUSS_TO_GAUSS = 1e-3
GPS_EPOCH_UNIX_S = 315_964_800
"""1980-01-06 00:00:00 UTC; GPS time runs 18 s ahead of UTC since 2017 (ignored: 6e-7 of a year)."""
SECONDS_PER_WEEK = 604_800
_TYPES = frozenset({"IMU", "IMU2", "IMU3", "MAG", "MAG2", "MAG3", "GPS", "GPS2", "GPA", "GPA2", "ATT"})
_EKF_NAMES = {0: "DCM", 1: "EKF1", 2: "EKF2", 3: "EKF3", 10: "SITL", 11: "external AHRS"}
_SKIPPED_BYTES = re.compile(r"Skipped (\d+) bad bytes")
RESTART_WINDOW = 16
"""IMU records (of all instances, in file order) on either side of a restart: every one after it is earlier than
every one before it. One damaged time, or instances a little out of order, cannot do that."""


def _time_ns(d: dict, name: str) -> int:
    """The record's time since boot: TimeUS, or TimeMS on old logs (an old GPS record's boot time is T)."""
    if "TimeUS" in d:
        return int(d["TimeUS"]) * 1000
    if name.startswith("GPS"):
        return int(d["T"]) * 1_000_000
    return int(d["TimeMS"]) * 1_000_000


def _instance(d: dict, name: str, base: str) -> int:
    """The sensor instance: field ``I`` on newer firmware, else the name's number (IMU2 -> 1)."""
    if "I" in d:
        return int(d["I"])
    suffix = name[len(base):]
    return int(suffix) - 1 if suffix else 0


def _healthy(d: dict, *flags: str) -> bool:
    return all(d.get(f, 1) != 0 for f in flags)


def _ekf_name(att_active: list[int], params: dict) -> str:
    """Whose attitude ATT is: ATT.AEKF (newer logs), else the AHRS_EKF_TYPE / AHRS_EKF_USE parameters."""
    if att_active:
        return _EKF_NAMES.get(Counter(att_active).most_common(1)[0][0], "AHRS")
    if "AHRS_EKF_TYPE" in params and math.isfinite(params["AHRS_EKF_TYPE"]):  # (a damaged log's may be NaN)
        return _EKF_NAMES.get(int(params["AHRS_EKF_TYPE"]), "AHRS")
    if "AHRS_EKF_USE" in params:
        return "EKF1" if params["AHRS_EKF_USE"] else "DCM"
    return "AHRS"


@contextlib.contextmanager
def _python_indexer():
    """DFReader's pure-Python record indexer: its complaints about corrupt bytes go to ``sys.stderr``
    (capturable), where the compiled one prints them to the process's file descriptors."""
    before = os.environ.get("PYMAVLINK_FAST_INDEX")
    os.environ["PYMAVLINK_FAST_INDEX"] = "0"
    try:
        yield
    finally:
        if before is None:
            del os.environ["PYMAVLINK_FAST_INDEX"]
        else:
            os.environ["PYMAVLINK_FAST_INDEX"] = before


def _read_records(path: Path, progress: TextIO | None = None) -> tuple[dict[str, list], dict, Counter]:
    """The records the import uses, as plain rows (of one boot: :func:`_one_boot`), the log's parameters, and what
    was skipped.

    Every record is parsed in file order (``recv_msg``): DFReader's by-type index stops at the first
    record of an unknown type, which a corrupt stretch of the log can fake, and would lose the rest.
    ``progress``: where to draw a bar of the records read (only if it is a terminal; the count DFReader's index
    found is its total).
    """
    from pymavlink.DFReader import DFReader_binary

    rows: dict[str, list] = defaultdict(list)
    order: dict[str, list[int]] = defaultdict(list)  # each row's place in the file
    skipped: Counter = Counter()
    chatter = io.StringIO()  # DFReader reports corruption with print(): count it instead
    with contextlib.redirect_stderr(chatter), contextlib.redirect_stdout(chatter), _python_indexer():
        log = DFReader_binary(str(path), zero_time_base=True)
        log.rewind()
        chatter.seek(0)
        chatter.truncate()  # the indexer's complaints; the parse below reports the same bytes once
        whole_to = log.offset  # where the last whole record ends
        try:
            for m in progress_bar(iter(log.recv_msg, None), sum(log.counts), "read", " records", progress):
                whole_to = log.offset
                name = m.get_type()
                if name in _TYPES:
                    try:
                        key = _add_record(rows, skipped, name, m.to_dict())
                    except (KeyError, TypeError, ValueError):  # a layout this importer does not know
                        skipped[f"unreadable_{name}"] += 1
                        continue
                    if key is not None:
                        order[key].append(whole_to)  # where it ends: grows in file order
            params = dict(log.params)
            if log.data_len > whole_to:  # DFReader stops silently inside a record it cannot read whole
                skipped["incomplete_tail_bytes"] = log.data_len - whole_to
        finally:
            log.close()
    text = chatter.getvalue()
    corrupt = sum(int(n) for n in _SKIPPED_BYTES.findall(text))
    if corrupt:
        skipped["corrupt_bytes"] = corrupt
    if "Failed to parse" in text:
        skipped["bad_record"] = text.count("Failed to parse")
    return _one_boot(rows, order, skipped), params, skipped


def _boot_starts(t: np.ndarray) -> list[int]:
    """Where in ``t`` (the IMU records' times, in file order) the clock starts again: a step back after which the
    next :data:`RESTART_WINDOW` times are all earlier than each of the :data:`RESTART_WINDOW` before it."""
    w = RESTART_WINDOW
    return [int(j) for j in np.flatnonzero(np.diff(t) < 0) + 1
            if w <= j <= len(t) - w and t[j:j + w].max() < t[j - w:j].min()]


def _one_boot(rows: dict[str, list], order: dict[str, list[int]], skipped: Counter) -> dict[str, list]:
    """The rows of the boot with the most IMU records (the first on ties); ``order`` gives each row's place in the
    file. The other boots' records are counted in ``skipped`` (``other_boots``, ``other_boot_records``)."""
    imu_keys = [k for k in rows if k.startswith("imu")]
    if not imu_keys:
        return rows
    places = np.concatenate([order[k] for k in imu_keys])
    in_file_order = np.argsort(places, kind="stable")
    times = np.concatenate([[r[0] for r in rows[k]] for k in imu_keys])[in_file_order]
    starts = places[in_file_order][_boot_starts(times)]  # where each later boot begins in the file
    if not len(starts):
        return rows
    chosen = int(np.argmax(np.bincount(np.searchsorted(starts, places, side="right"), minlength=len(starts) + 1)))
    kept: dict[str, list] = defaultdict(list)
    for key, key_rows in rows.items():
        boot = np.searchsorted(starts, order[key], side="right")
        kept[key] = [r for r, b in zip(key_rows, boot.tolist()) if b == chosen]
        skipped["other_boot_records"] += len(key_rows) - len(kept[key])
    skipped["other_boots"] = len(starts)
    return kept


def _add_record(rows: dict[str, list], skipped: Counter, name: str, d: dict) -> str | None:
    """File one IMU, MAG, GPS, GPA or ATT record under its stream (imu0, mag1, gps, gpa, att) and return the
    stream's name, or None if it was skipped (counted). A field missing from the record's layout raises KeyError
    (counted by the caller)."""
    t = _time_ns(d, name)  # the earliest GPS layouts have no boot time (no T): unreadable, counted
    if not 0 <= t < MAX_TIME_NS:  # a damaged record's time: it would land anywhere in the flight
        skipped[f"time_out_of_range_{name}"] += 1
        return None
    if name.startswith("IMU"):
        if not _healthy(d, "GH", "AH", "GyHlt", "AcHlt"):
            skipped["imu_unhealthy"] += 1
            return None
        key, row = f"imu{_instance(d, name, 'IMU')}", (t, d["GyrX"], d["GyrY"], d["GyrZ"], d["AccX"], d["AccY"], d["AccZ"])
    elif name.startswith("MAG"):
        if not _healthy(d, "Health"):
            skipped["mag_unhealthy"] += 1
            return None
        key, row = f"mag{_instance(d, name, 'MAG')}", (t, d["MagX"], d["MagY"], d["MagZ"])
    elif name.startswith("GPS"):
        if _instance(d, name, "GPS") != 0:
            skipped["gps_second_receiver"] += 1
            return None
        week, week_ms = (d["GWk"], d["GMS"]) if "GWk" in d else (d["Week"], d["TimeMS"])
        key, row = "gps", (t, int(d["Status"]), d["Lat"], d["Lng"], d["Alt"], d["Spd"], d["GCrs"], d.get("VZ"), week, week_ms)
    elif name.startswith("GPA"):
        if _instance(d, name, "GPA") != 0:
            return None
        key, row = "gpa", (t, d["SAcc"])
    else:  # ATT
        key, row = "att", (t, d["Roll"], d["Pitch"], d["Yaw"], d.get("AEKF"))
    rows[key].append(row)
    return key


def _gnss(gps: list, gpa: list) -> tuple[list[GnssSample], float | None]:
    """GnssSamples of the primary receiver, and the GPS time of its first 3-D fix (Unix seconds)."""
    speed_accuracy = {t: acc for t, acc in gpa}
    fixes, first_unix = [], None
    for t, status, lat, lng, alt, spd, crs, vz, week, week_ms in gps:
        course = math.radians(crs)
        vel = (spd * math.cos(course), spd * math.sin(course), vz or 0.0) if status >= 2 else None
        has_position = status >= 2 and not (lat == 0 and lng == 0)
        acc = speed_accuracy.get(t)
        fixes.append(GnssSample(t, status, vel, status >= 3 and vz is not None, acc if acc else None,  # type: ignore[arg-type]
                                lat if has_position else None, lng if has_position else None,
                                alt if has_position else None, False, MAVLINK_SOURCE))
        if first_unix is None and status >= 3 and week > 0:
            first_unix = GPS_EPOCH_UNIX_S + week * SECONDS_PER_WEEK + week_ms * 1e-3
    return fixes, first_unix


def read_dataflash(path: str | Path, start_s: float = 0.0, duration_s: float | None = None, field_rest_s: float = 2.0,
                   progress: TextIO | None = None) -> SensorData:
    """An ArduPilot DataFlash log's IMUs, magnetometers, GPS and ATT in the project's conventions
    (module docstring); ``start_s``/``duration_s`` cut it, counted from the first IMU sample; ``progress``: where to
    draw a bar while the records are read (only if it is a terminal)."""
    path = Path(path)
    rows, params, skipped = _read_records(path, progress)
    instances = sorted(int(k[3:]) for k in rows if k.startswith("imu"))
    if not instances:  # (an instance the cut leaves empty is dropped below)
        damage = f" (DFReader skipped {skipped['corrupt_bytes']:,} corrupt bytes: a damaged one?)" if skipped["corrupt_bytes"] else ""
        raise ValueError(f"{path} has no IMU records: not an ArduPilot DataFlash log, or one without IMU logging{damage}")
    data = {k: np.array(v, dtype=float) for k, v in rows.items() if k.startswith(("imu", "mag"))}
    t0 = int(data[f"imu{instances[0]}"][:, 0].min()) + round(start_s * 1e9)  # the earliest: a damaged first record's may lie ahead
    t1 = None if duration_s is None else t0 + round(duration_s * 1e9)

    def rows_inside(a: np.ndarray) -> np.ndarray:
        return a[in_cut(a[:, 0], t0, t1)]

    imus = []
    for i in instances:
        raw = rows_inside(data[f"imu{i}"])
        if not len(raw):
            continue
        t_ns = raw[:, 0].astype(np.int64)
        mag = None
        if f"mag{i}" in data:
            mag_rows = rows_inside(data[f"mag{i}"])
            mag, late = mag_on_next_imu(t_ns, mag_rows[:, 0].astype(np.int64), mag_rows[:, 1:] * MGAUSS_TO_GAUSS)
            if late:
                skipped["mag_after_last_imu"] += late
        imus.append(ImuStream(i, t_ns, raw[:, 1:4], raw[:, 4:7], mag))
    if not imus:
        first = data[f"imu{instances[0]}"][:, 0]
        raise EmptyCut(float(first.max() - first.min()) / 1e9)
    for key in data:
        if key.startswith("mag") and int(key[3:]) not in instances:
            skipped["mag_without_imu"] += len(data[key])
    att = [r for r in rows.get("att", []) if in_cut(r[0], t0, t1)]
    ref_t = np.array([r[0] for r in att], dtype=np.int64)
    ref_q = np.array([quaternion_from_euler(*np.radians(r[1:4])) for r in att]).reshape(-1, 4)
    gnss, first_unix = _gnss([r for r in rows.get("gps", []) if in_cut(r[0], t0, t1)], rows.get("gpa", []))
    ekf = _ekf_name([int(r[4]) for r in att if r[4] is not None], params)
    field_ned, field_source = field_from_gnss(gnss, first_unix), "World Magnetic Model at the first 3-D fix (declination included)"
    primary = imus[0]
    if field_ned is None and primary.mag is not None:
        rest = (primary.t_ns < primary.t_ns[0] + round(field_rest_s * 1e9)) & ~np.isnan(primary.mag[:, 0])
        field_ned, field_source = field_from_rest(primary.accel[rest], primary.mag[rest]), rest_field_source(field_rest_s)
    seconds = (primary.t_ns[-1] - primary.t_ns[0]) * 1e-9
    rates = ", ".join(f"{len(s.t_ns) / max(seconds, 1e-9):.0f} Hz" for s in imus)
    return SensorData(
        imus=imus,
        ref_t_ns=ref_t,
        ref_q=ref_q,
        reference=f"{ekf} (ArduPilot ATT: the autopilot's estimate, NOT ground truth)",
        attribution=f"ArduPilot DataFlash log {path.name}; converted to MAVLink and cut by bingham-fuser import (the log's own terms apply).",
        source=f"ArduPilot DataFlash {path.name}: IMU instances {instances} ({rates}), {len(gnss)} GPS fixes, "
               f"{len(att)} ATT, from {start_s:g} s" + (f" for {duration_s:g} s" if duration_s else ""),
        mag_field_ned_gauss=field_ned,
        field_source=field_source,
        attitude_stream=True,
        attitude_message="ATTITUDE",
        gnss=gnss,
        skipped=dict(skipped),
    )
