""".tlog replay: every packet the live decoder accepts, with the log's receive times, on real-shaped logs.

The logs are built by tests/tlog_builder.py (ArduPilot ground-station shape: three IMUs with their
own types and clocks at telemetry or companion rates, ArduPilot-only messages, parameter bursts,
a reboot, radio damage, garbage, absurd record times). "Decodable" is counted independently by
pymavlink's own reader (``mavlink_connection(path, dialect="ardupilotmega")`` and ``recv_msg``) and
by the builder (the IMU packets it wrote undamaged).
"""

from __future__ import annotations

import dataclasses
import logging
import re
import struct
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as apm

from drivers import ImuSample, LinkSettings, TlogSource
from fuser.cli import main
from fuser.config import FuserConfig
from fuser.replay import replay
from tlog_builder import COMPANION, IMU_TYPES, TlogShape, build_tlog



@pytest.fixture(autouse=True)
def _quiet_reason_log(caplog):
    caplog.set_level(logging.ERROR, logger="drivers")


def pymavlink_imu_count(path: Path) -> int:
    """IMU messages pymavlink alone decodes from the file: the independent count of 'decodable'."""
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    n = 0
    while (msg := conn.recv_msg()) is not None:
        n += msg.get_type() in IMU_TYPES
    conn.close()
    return n


@pytest.fixture(scope="module")
def telemetry_log(tmp_path_factory):
    return build_tlog(tmp_path_factory.mktemp("tlog") / "telemetry.tlog", TlogShape(duration_s=60.0, reboot_at_s=35.0))


def test_telemetry_rate_log_replays_99_percent_of_decodable_imu_and_says_so(telemetry_log, tmp_path, capsys):
    """With the default settings: the loop's wait adapts to the radio's latency spread (20 ms air frames plus
    queueing, up to about 150 ms; a fixed 5 ms wait let 8% of the IMU samples through)."""
    assert main(["replay", str(telemetry_log.path), "-o", str(tmp_path / "out.mcap")]) == 0
    out, err = capsys.readouterr()
    line = next(x for x in out.splitlines() if "IMU messages used" in x)
    m = re.fullmatch(r"telemetry\.tlog: ([\d,]+) of ([\d,]+) IMU messages used \(([\d.]+)%\); .*", line)
    assert m, line
    used, decodable = (int(g.replace(",", "")) for g in m.groups()[:2])
    assert decodable == telemetry_log.imu_intact  # every undamaged IMU packet the builder wrote was decoded
    assert used >= 0.99 * pymavlink_imu_count(telemetry_log.path)
    assert used >= 0.99 * telemetry_log.imu_intact
    assert "warning" not in err
    refused = next(x for x in out.splitlines() if "not used:" in x)
    for reason in ("bad_crc", "garbage", "unframed", "record_time_absurd", "other_sender"):
        assert f"{reason}=" in refused, refused
    for counted in ("lost", "reboot"):  # counted, but no refusals (drivers/README.md): with what was used
        assert f"{counted}=" in line.partition("also counted: ")[2] and f"{counted}=" not in refused, (line, refused)


def test_the_reader_finds_every_imu_packet_pymavlink_finds(telemetry_log):
    with TlogSource(telemetry_log.path) as src:
        list(src.samples())
        ours = sum(src.decoder.received[t] for t in IMU_TYPES)
    assert ours == telemetry_log.imu_intact >= pymavlink_imu_count(telemetry_log.path)


def test_decoded_values_are_the_simulated_measurements_in_order(telemetry_log):
    """Each IMU type's decoded gyro readings are, in order, a subsequence of what the builder sent."""
    with TlogSource(telemetry_log.path) as src:
        got = [s for s, _ in src.samples() if isinstance(s, ImuSample)]
    instance_of = {"RAW_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
    for kind, sent in telemetry_log.imu_sent.items():
        decoded = [tuple(round(v * 1000) for v in s.gyro_rad_s) for s in got if s.source.instance == instance_of[kind]]
        it = iter(g for _, g in sent)
        assert all(any(d == g for g in it) for d in decoded), kind
    # every undamaged IMU packet, but the first of each IMU after the reboot (it waits for the next to confirm the new clock)
    assert len(got) == telemetry_log.imu_intact - 3


def test_sequence_gaps_count_the_autopilot_packets_the_log_lacks(telemetry_log):
    with TlogSource(telemetry_log.path) as src:
        list(src.samples())
        stats = src.stats
    # frames the radio lost or damaged (damaged ones fail their CRC) leave gaps in the autopilot's sequence;
    # the reboot restarts it and must not count as a loss
    assert telemetry_log.autopilot_missing - 10 <= stats["lost"] <= telemetry_log.autopilot_missing


def test_companion_rate_log_replays_every_imu_message(tmp_path):
    built = build_tlog(tmp_path / "companion.tlog", dataclasses.replace(COMPANION, duration_s=8.0, reboot_at_s=5.0, reboot_silent_s=1.5))
    summary = replay(built.path, tmp_path / "out.mcap", FuserConfig(), progress=None)
    report = summary.inputs
    assert report.imu_decodable == built.imu_intact
    assert report.imu_used >= 0.99 * pymavlink_imu_count(built.path)
    assert report.warning() is None


def test_the_wrong_vehicle_is_one_line_naming_why(telemetry_log, tmp_path, capsys):
    """--system 7 on a log of system 1: nothing to fuse, so a runtime error (exit 1) whose one line says why."""
    assert main(["replay", str(telemetry_log.path), "-o", str(tmp_path / "out.mcap"), "--system", "7"]) == 1
    _, err = capsys.readouterr()
    assert len(err.strip().splitlines()) == 1
    assert "nothing to replay" in err and "other_sender=" in err
    assert not (tmp_path / "out.mcap").exists()


# ---------------------------------------------------------------- record framing, hand-built

T0_US = 1_700_000_000_000_000


def imu_packet(i: int, seq: int) -> bytes:
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq
    return bytes(apm.MAVLink_raw_imu_message(10_000_000 + 10_000 * i, 0, 0, -1000, i, 0, 0, 0, 0, 0, 0, 0).pack(mav))


def write_log(path: Path, records: list[tuple[int, bytes]]) -> Path:
    path.write_bytes(b"".join(struct.pack(">Q", t) + p for t, p in records))
    return path


def read(path: Path) -> tuple[list[tuple[int, int]], TlogSource]:
    src = TlogSource(path, LinkSettings(lock_first_autopilot=False))
    out = [(s.gyro_rad_s[0] * 1000, receive_ns) for s, receive_ns in src.samples()]
    return [(round(g), r) for g, r in out], src


def test_an_absurd_record_time_is_counted_and_not_used(tmp_path):
    times = [T0_US + 10_000 * i for i in range(6)]
    times[3] = T0_US + 400 * 86_400 * 10**6  # 400 days ahead: a damaged high byte
    got, src = read(write_log(tmp_path / "a.tlog", [(t, imu_packet(i, i)) for i, t in enumerate(times)]))
    assert [g for g, _ in got] == list(range(6))  # the packet itself is used
    assert [r for _, r in got] == [(T0_US + 10_000 * i) * 1000 for i in (0, 1, 2, 2, 4, 5)]
    assert src.stats["record_time_absurd"] == 1


def test_a_ground_station_clock_step_confirmed_by_the_next_record_is_adopted(tmp_path):
    step = 2 * 3600 * 10**6  # the ground station's clock was set two hours ahead
    times = [T0_US, T0_US + 10_000, T0_US + step, T0_US + step + 10_000, T0_US + step + 20_000]
    got, src = read(write_log(tmp_path / "s.tlog", [(t, imu_packet(i, i)) for i, t in enumerate(times)]))
    assert [r for _, r in got] == [T0_US * 1000, (T0_US + 10_000) * 1000, (T0_US + 10_000) * 1000,
                                   (times[3]) * 1000, times[4] * 1000]
    assert src.stats["record_time_absurd"] == 1 and src.stats["record_clock_step"] == 1


def test_garbage_between_records_and_a_cut_last_record(tmp_path):
    packets = [imu_packet(i, i) for i in range(5)]
    data = b"".join(struct.pack(">Q", T0_US + 10_000 * i) + p + (b"\xfd\x40junk" * (i == 1)) for i, p in enumerate(packets))
    path = tmp_path / "g.tlog"
    path.write_bytes(data + struct.pack(">Q", T0_US + 60_000) + imu_packet(5, 5)[:20])
    got, src = read(path)
    assert [g for g, _ in got] == [0, 1, 2, 3, 4]
    assert src.stats["unframed"] >= 1 and src.stats["truncated"] >= 1


@pytest.mark.parametrize("content", [b"", b"\x00" * 7, bytes(range(256)) * 40, b"not a telemetry log\n" * 100])
def test_files_that_are_not_logs_give_nothing_and_raise_nothing(tmp_path, content):
    path = tmp_path / "x.tlog"
    path.write_bytes(content)
    got, src = read(path)
    assert got == [] and src.stats["accepted"] == 0


def test_a_telemetry_log_named_in_capitals_is_replayed_as_one(telemetry_log, tmp_path):
    """FAT-formatted cards and some Windows tools name files in capitals (FLIGHT.TLOG, as ArduPilot's own 00000042.BIN):
    the name's case does not change what the file is. It was refused as 'not an MCAP file'."""
    upper = tmp_path / "FLIGHT.TLOG"
    upper.write_bytes(telemetry_log.path.read_bytes())
    summary = replay(upper, tmp_path / "out.mcap", FuserConfig(), progress=None)
    assert summary.inputs is not None and summary.inputs.imu_decodable == telemetry_log.imu_intact
    assert summary.inputs.imu_used >= 0.99 * telemetry_log.imu_intact
