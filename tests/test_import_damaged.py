"""``bingham-fuser import`` of damaged logs: a record whose time or value a damaged file made absurd is counted
and left out, and the rest of the log is imported as if it were not there.

Found by flipping random bytes of real and real-shaped logs (pyulog's sample.ulg, the DataFlash writer's
flight): a ULog or DataFlash record with a time beyond 2^63 ns stopped the import with an internal error (the
MAVLink encoder's ``struct.error``), one beyond int64 made the DataFlash reader fail the whole file, and one
magnetometer sample of 10^14 gauss in the first two seconds became the reference field (1.5e11 gauss) that every
heading was to be measured against.

The logs here are a vehicle at rest, level, facing north, in a field of (0.2, 0, 0.45) gauss, so the reference
field the importer must find is that one exactly (norm and dip of the undamaged samples).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.mavlink_encode import MavlinkEncoder, UnencodableSample
from drivers.samples import GnssSample, ImuSample, SourceId
from fuser.dataflash import read_dataflash
from fuser.importers import ImuStream, SensorData, import_log, read_px4, write_mcap
from fuser.record import read_log

from dataflash_writer import DataFlashWriter
from ulog_writer import ULogWriter

FIELD_NED_GAUSS = (0.2, 0.0, 0.45)
GRAVITY = (0.0, 0.0, -9.80665)  # FRD, level: the accelerometer reads the reaction, up
BEYOND_INT64_US = 2**64 - 2**11  # a float64 exactly, as the DataFlash writer packs it
SOURCE = SourceId("mavlink", 1, 1, 0)


def _dataflash(path: Path) -> int:
    """3 s at 200 Hz (IMU), 20 Hz (MAG), 5 Hz (2-D GPS fixes) and 25 Hz (ATT); damaged: an IMU record's time, a
    MAG record at the int16's end (32.8 gauss) in the first 2 s, a GPS record's speed (NaN). Returns where its
    last record (an IMU record) starts."""
    w = DataFlashWriter()
    w.declare(76, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    w.declare(80, "MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
    w.declare(82, "GPS", "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U")
    w.declare(86, "ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF")
    for k in range(600):
        t_us = 1_000_000 + 5_000 * k
        w.write("IMU", TimeUS=BEYOND_INT64_US if k == 300 else t_us, I=0, GyrX=0.0, GyrY=0.0, GyrZ=0.0, AccX=GRAVITY[0],
                AccY=GRAVITY[1], AccZ=GRAVITY[2], EG=0, EA=0, T=40.0, GH=1, AH=1, GHz=1000, AHz=1000)
        if k % 10 == 3:
            mag_mg = (32767, 0, 0) if k == 103 else tuple(round(v * 1000) for v in FIELD_NED_GAUSS)
            w.write("MAG", TimeUS=t_us + 100, I=0, MagX=mag_mg[0], MagY=mag_mg[1], MagZ=mag_mg[2], OfsX=0, OfsY=0, OfsZ=0,
                    MOX=0, MOY=0, MOZ=0, Health=1, S=t_us)
        if k % 40 == 7:
            w.write("GPS", TimeUS=t_us + 200, I=0, Status=2, GMS=0, GWk=0, NSats=6, HDop=2.0, Lat=52.5, Lng=13.4, Alt=40.0,
                    Spd=float("nan") if k == 207 else 0.0, GCrs=0.0, VZ=0.0, Yaw=0.0, U=1)
        if k % 8 == 5:
            w.write("ATT", TimeUS=t_us + 300, DesRoll=0, Roll=0, DesPitch=0, Pitch=0, DesYaw=0, Yaw=0, ErrRP=0.0, ErrYaw=0.0, AEKF=3)
    path.write_bytes(bytes(w.data))
    return w.last_record_at


SENSOR_COMBINED = [("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("float[3]", "accelerometer_m_s2"),
                   ("float[3]", "magnetometer_ga")]
VEHICLE_ATTITUDE = [("uint64_t", "timestamp"), ("float[4]", "q")]


def _ulog(path: Path, attitude: bool = True) -> int:
    """3 s of sensor_combined at 250 Hz and vehicle_attitude at 50 Hz; damaged: a sensor_combined record's time
    (beyond 2^63 us: negative as int64), a magnetometer reading of 3e5 gauss in the first 2 s, a vehicle_attitude
    record's time and another's quaternion (zeros), and a data record for a message id nothing subscribed.
    Returns where its last message (a sensor_combined record) starts."""
    w = ULogWriter(start_us=1_000_000)
    w.topic("sensor_combined", SENSOR_COMBINED)
    if attitude:
        w.topic("vehicle_attitude", VEHICLE_ATTITUDE)
    for k in range(750):
        t_us = 1_000_000 + 4_000 * k
        mag = (3e5, 0.0, 0.0) if k == 100 else FIELD_NED_GAUSS
        w.write("sensor_combined", timestamp=2**63 + 7 if k == 400 else t_us, gyro_rad=(0.0, 0.0, 0.0),
                accelerometer_m_s2=GRAVITY, magnetometer_ga=mag)
        if attitude and k % 5 == 2:
            w.write("vehicle_attitude", timestamp=BEYOND_INT64_US if k == 502 else t_us + 100,
                    q=(0.0, 0.0, 0.0, 0.0) if k == 602 else (1.0, 0.0, 0.0, 0.0))
        if k == 600:
            w.data += struct.pack("<H", 11) + b"D" + struct.pack("<H", 999) + bytes(9)  # msg id 999: never subscribed
    path.write_bytes(bytes(w.data))
    return w.last_message_at


def test_a_damaged_dataflash_log_imports_the_rest_and_counts_what_it_left_out(tmp_path):
    _dataflash(tmp_path / "damaged.bin")
    s = import_log(tmp_path / "damaged.bin", tmp_path / "out.mcap")
    assert s.skipped["time_out_of_range_IMU"] == 1
    assert s.decoder_stats["non_finite"] == 1  # the speed of NaN: sent as GPS_INPUT (floats), refused on arrival
    assert s.decoder_stats["mag_out_of_range"] == 1  # the 32.8-gauss reading's IMU sample, refused on arrival
    assert s.imu == 598 and s.gnss == 14
    assert s.mag_field_ned_gauss == pytest.approx(FIELD_NED_GAUSS, abs=1e-9)  # the 32.8-gauss reading left out


def test_a_damaged_ulog_imports_the_rest_and_counts_what_it_left_out(tmp_path):
    pytest.importorskip("pyulog")
    _ulog(tmp_path / "damaged.ulg")
    s = import_log(tmp_path / "damaged.ulg", tmp_path / "out.mcap")
    assert s.skipped == {"time_out_of_range_sensor_combined": 1, "time_out_of_range_vehicle_attitude": 1, "unknown_message_id": 1,
                         "corrupt_data": 1, "out_of_range_ATTITUDE_QUATERNION": 1}  # pyulog calls the unknown id corrupt
    assert s.attitude == 148 and s.truth == 148
    assert s.mag_field_ned_gauss == pytest.approx(FIELD_NED_GAUSS, abs=1e-6)  # float32 values; the 3e5 one left out
    assert s.decoder_stats["mag_out_of_range"] == 1  # and its sample refused by the decoder, as any other would be


@pytest.mark.parametrize("suffix", [".bin", ".ulg"])
@pytest.mark.parametrize("left", [1, 2, 3, 20])
def test_a_log_cut_inside_its_last_record_says_how_much_it_left(tmp_path, suffix, left):
    """Power lost while the log was written: the file ends ``left`` bytes into its last record (inside the
    record's header, or into its body). DFReader and pyulog both stop there in silence; the import counts the
    bytes, and imports everything before them as it imports the whole log."""
    if suffix == ".ulg":
        pytest.importorskip("pyulog")
    last = {".bin": _dataflash, ".ulg": _ulog}[suffix](tmp_path / f"whole{suffix}")
    (tmp_path / f"cut{suffix}").write_bytes((tmp_path / f"whole{suffix}").read_bytes()[: last + left])
    whole = import_log(tmp_path / f"whole{suffix}", tmp_path / "whole.mcap")
    cut = import_log(tmp_path / f"cut{suffix}", tmp_path / "cut.mcap")
    assert "incomplete_tail_bytes" not in whole.skipped
    assert cut.skipped == {**whole.skipped, "incomplete_tail_bytes": left}
    assert cut.imu == whole.imu - 1 and (cut.gnss, cut.attitude) == (whole.gnss, whole.attitude)


def test_the_command_line_warns_that_a_log_was_cut_short(tmp_path, capsys):
    from fuser.cli import main

    last = _dataflash(tmp_path / "whole.bin")
    (tmp_path / "cut.bin").write_bytes((tmp_path / "whole.bin").read_bytes()[: last + 20])
    assert main(["import", str(tmp_path / "cut.bin"), "-o", str(tmp_path / "cut.mcap")]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "cut short" in line]
    assert warnings == [(f"bingham-fuser: warning: {tmp_path / 'cut.bin'} ends with 20 bytes that are not a whole record: cut short "
                         "(power lost while logging, a download that stopped?) or garbage after the last record; imported what is there")]


def test_a_ulog_with_appended_data_cut_before_or_inside_the_appended_part_says_so(tmp_path):
    """PX4 appends data after a crash (flag bits: DATA_APPENDED and the offset where it starts). A download cut
    before that offset, or inside the appended part, is counted as any other cut (the walk starts at the last
    offset within the file). Only the count is checked: pyulog returns an appended part's records as a second
    data set of the same topic, of which the import takes one (left alone: PX4 appends only after a crash)."""
    pytest.importorskip("pyulog")
    w = ULogWriter(start_us=1_000_000)
    w.topic("sensor_combined", SENSOR_COMBINED)
    w.topic("vehicle_attitude", VEHICLE_ATTITUDE)

    def at_rest(k: int) -> None:
        w.write("sensor_combined", timestamp=1_000_000 + 4_000 * k, gyro_rad=(0.0, 0.0, 0.0), accelerometer_m_s2=GRAVITY,
                magnetometer_ga=FIELD_NED_GAUSS)
        if k % 5 == 2:
            w.write("vehicle_attitude", timestamp=1_000_000 + 4_000 * k + 100, q=(1.0, 0.0, 0.0, 0.0))

    for k in range(600):
        at_rest(k)
    last_main = w.last_message_at
    w.data[16 + 3 + 8] |= 1  # the flag bits' first incompat byte: DATA_APPENDED
    struct.pack_into("<Q", w.data, 16 + 3 + 16, len(w.data))  # the first appended-data offset: here
    w.subscribe()  # the appended part subscribes again (pyulog forgets the subscriptions at each offset)
    for k in range(600, 700):
        at_rest(k)
    whole = bytes(w.data)
    for name, end, left in (("whole", len(whole), 0), ("main", last_main + 5, 5), ("appended", w.last_message_at + 7, 7)):
        (tmp_path / f"{name}.ulg").write_bytes(whole[:end])
        s = import_log(tmp_path / f"{name}.ulg", tmp_path / f"{name}.mcap")
        assert s.skipped.get("incomplete_tail_bytes", 0) == left, (name, s.skipped)


SAMPLE_ULG = Path(__file__).resolve().parents[2] / "shared" / "data" / "px4" / "sample.ulg"


@pytest.mark.skipif(not SAMPLE_ULG.is_file(), reason="../shared/data/px4/sample.ulg is not beside the repository")
@pytest.mark.parametrize("fraction", [0.3, 0.7, 0.999])
def test_a_real_ulog_cut_anywhere_loses_only_its_incomplete_tail(tmp_path, fraction):
    """PX4's sample flight (pyulog's, BSD-3): whole, nothing is left over; cut anywhere, the bytes said to be left
    over are exactly what pyulog, reading independently, cannot use: without them it reads the same records, and
    a file that ends at the boundary the walk found has nothing left over."""
    pyulog = pytest.importorskip("pyulog")
    from fuser.importers import ulog_incomplete_tail_bytes

    assert ulog_incomplete_tail_bytes(SAMPLE_ULG) == 0
    data = SAMPLE_ULG.read_bytes()
    cut = int(fraction * len(data))
    (tmp_path / "cut.ulg").write_bytes(data[:cut])
    left = ulog_incomplete_tail_bytes(tmp_path / "cut.ulg")
    (tmp_path / "boundary.ulg").write_bytes(data[: cut - left])
    assert 0 < left < cut and ulog_incomplete_tail_bytes(tmp_path / "boundary.ulg") == 0

    def records(path: Path) -> dict:
        return {(d.name, d.multi_id): len(d.data["timestamp"]) for d in pyulog.ULog(str(path), ["sensor_combined", "vehicle_attitude"]).data_list}

    assert records(tmp_path / "cut.ulg") == records(tmp_path / "boundary.ulg")


def test_a_ulog_without_the_attitude_topic_is_one_clear_error(tmp_path):
    pytest.importorskip("pyulog")
    _ulog(tmp_path / "no_attitude.ulg", attitude=False)
    with pytest.raises(ValueError, match="no_attitude.ulg has no vehicle_attitude data"):
        import_log(tmp_path / "no_attitude.ulg", tmp_path / "out.mcap")


@pytest.mark.parametrize("sample, message", [
    (ImuSample(-5_000, (0.0, 0.0, 0.0), GRAVITY, None, SOURCE), "HIGHRES_IMU"),  # before time 0: uint64 us
    (ImuSample(2**80, (0.0, 0.0, 0.0), GRAVITY, None, SOURCE), "RAW_IMU"),
    (GnssSample(1_000, 3, (float("nan"), 0.0, 0.0), True, None, 52.5, 13.4, 40.0, False, SOURCE), "GPS_RAW_INT"),
    (GnssSample(1_000, 3, (1.0, 0.0, 0.0), True, float("inf"), 52.5, 13.4, 40.0, False, SOURCE), "GPS_RAW_INT"),
    (GnssSample(1_000, 3, (1.0, 0.0, 0.0), True, None, 52.5, 13.4, 1e12, False, SOURCE), "GLOBAL_POSITION_INT"),
])
def test_a_sample_its_message_cannot_hold_sends_nothing(sample, message):
    """The encoder refuses it (UnencodableSample) and leaves its stream as it was: the next frame, HEARTBEAT
    included, is the one a fresh encoder would send."""
    encoder = MavlinkEncoder()
    with pytest.raises(UnencodableSample, match=message):
        encoder.encode(sample, message)
    good = ImuSample(2_000_000, (0.01, 0.0, 0.0), GRAVITY, FIELD_NED_GAUSS, SOURCE)
    assert encoder.encode(good) == MavlinkEncoder().encode(good)


def test_a_message_that_is_not_the_samples_is_a_usage_error_not_a_damaged_sample():
    with pytest.raises(ValueError) as exc:
        MavlinkEncoder().encode(ImuSample(0, (0.0, 0.0, 0.0), GRAVITY, None, SOURCE), "ATTITUDE")
    assert not isinstance(exc.value, UnencodableSample)


def test_a_value_the_link_cannot_carry_is_left_out_and_the_metadata_says_so(tmp_path):
    """A fix with a latitude of NaN reaches the encoder (a ULog's ``latitude_deg`` is a double): GPS_INPUT carries
    it in 1e-7 degrees, an integer. It is counted beside what the reader left out, in the summary and in the
    file's metadata (written again at the end, complete; a reader takes the last)."""
    t = np.arange(400, dtype=np.int64) * 5_000_000
    imu = ImuStream(0, t, np.zeros((400, 3)), np.tile(GRAVITY, (400, 1)), np.tile(FIELD_NED_GAUSS, (400, 1)))
    fixes = [GnssSample(int(t[k]), 3, (0.0, 0.0, 0.0), True, 0.3, float("nan") if k == 200 else 52.5, 13.4, 40.0, False, SOURCE)
             for k in range(0, 400, 40)]
    data = SensorData([imu], t[::10], np.tile([1.0, 0.0, 0.0, 0.0], (40, 1)), "truth", "none", "test", FIELD_NED_GAUSS,
                      gnss=fixes, skipped={"bad_record": 2})
    s = write_mcap(data, tmp_path / "out.mcap")
    assert s.skipped == {"bad_record": 2, "out_of_range_GPS_INPUT": 1} and s.gnss == 9 and s.imu == 400
    assert read_log(tmp_path / "out.mcap").metadata["bingham_fuser"]["skipped"] == "bad_record=2, out_of_range_GPS_INPUT=1"


def test_a_dataflash_log_whose_imu_format_is_damaged_says_it_may_be_damaged(tmp_path):
    """The IMU's FMT record hit (its header bytes): DFReader cannot read a single IMU record and skips them as
    corrupt bytes; the error says so instead of only "not a DataFlash log"."""
    _dataflash(tmp_path / "damaged.bin")
    data = bytearray((tmp_path / "damaged.bin").read_bytes())
    fmt_imu = data.index(b"\xa3\x95\x80\x4c")  # FMT (128) declaring type 76, IMU
    data[fmt_imu : fmt_imu + 2] = b"\x00\x00"
    (tmp_path / "damaged.bin").write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"has no IMU records: .* \(DFReader skipped [\d,]+ corrupt bytes: a damaged one\?\)"):
        import_log(tmp_path / "damaged.bin", tmp_path / "out.mcap")


@pytest.mark.parametrize("fmt", ["dataflash", "px4"])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(damage=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=60),
       cut=st.one_of(st.none(), st.floats(0.05, 1.0)))
def test_whatever_the_damage_the_reader_refuses_the_file_or_the_import_completes(fmt, damage, cut, tmp_path):
    """Random bytes overwritten and the file cut short: the log's reader (pyulog, DFReader, each with the
    project's checks) may refuse the file, which the command line reports as one line naming it; once read,
    writing the MCAP never raises (found by hand before: struct.error, OverflowError, a zero quaternion). That is
    the check; the last assertion only says that something was imported or counted."""
    if fmt == "px4":
        pytest.importorskip("pyulog")
    path = tmp_path / ("log.ulg" if fmt == "px4" else "log.bin")
    (_ulog if fmt == "px4" else _dataflash)(path)
    data = bytearray(path.read_bytes())
    for where, value in damage:
        data[int(where * len(data))] = value
    path.write_bytes(bytes(data[: int(cut * len(data))] if cut is not None else data))
    reader = {"px4": read_px4, "dataflash": read_dataflash}[fmt]
    try:
        sensor_data = reader(path)
    except Exception:  # noqa: BLE001 - refused: fuser.cli turns any reader error into one line (NotALogError)
        return
    summary = write_mcap(sensor_data, tmp_path / "out.mcap")
    assert summary.imu + sum(summary.skipped.values()) + sum(summary.decoder_stats.values()) > 0


def test_a_reference_field_no_magnetometer_reads_is_replaced_by_the_default_and_counted(tmp_path):
    """An EKF2 field state or readings a damaged log made absurd: the TOML would hold a field the configuration
    refuses (tests/test_config.py), so the default goes in and the metadata says why."""
    t = np.arange(40, dtype=np.int64) * 5_000_000
    imu = ImuStream(0, t, np.zeros((40, 3)), np.tile(GRAVITY, (40, 1)), None)
    data = SensorData([imu], t, np.tile([1.0, 0.0, 0.0, 0.0], (40, 1)), "truth", "none", "test", (1.5e11, 0.0, 3.1e11),
                      field_source="EKF2 earth-field state")
    s = write_mcap(data, tmp_path / "out.mcap", tmp_path / "out.toml")
    assert s.skipped == {"field_out_of_range": 1} and s.mag_field_ned_gauss == (0.21, 0.0, 0.43)
    meta = read_log(tmp_path / "out.mcap").metadata["bingham_fuser"]
    assert meta["mag_field_source"].startswith("none in the log: the default (EKF2 earth-field state: [")
    assert "field_ned_gauss = [0.21, 0.0, 0.43]" in (tmp_path / "out.toml").read_text()
