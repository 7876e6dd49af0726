"""A .tlog in a batch: when little of its IMU data reaches the loop, the summary says so, as ``replay LOG`` does.

A telemetry log replaying with a small share of its IMU messages and exit 0 was a past bug of this project;
``replay LOG -o OUT`` now warns (:meth:`fuser.inputs.InputReport.warning`), but the batch's summary showed such a
log as ``ok`` with its sample count and nothing else. The log here holds two vehicles: the fuser takes the first
autopilot it hears (system 1), which sends one IMU message in ten; system 2 sends the rest.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from fuser import batch  # noqa: E402
from fuser.batch import run_batch  # noqa: E402
from fuser.config import FuserConfig  # noqa: E402
from fuser.replay import replay  # noqa: E402

IMU_HZ = 100
SECONDS = 5
T0_US = 1_700_000_000_000_000  # the ground station's receive clock (Unix us)


def _packet(system: int, seq: int, t_us: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=1)
    mav.seq = seq % 256
    msg = mavlink.MAVLink_highres_imu_message(t_us, 0.0, 0.0, -9.81, 0.001, -0.002, 0.01, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0x3F, 0)
    return bytes(msg.pack(mav))


def write_two_vehicle_tlog(path: Path) -> tuple[int, int]:
    """The log; returns (IMU messages of system 1, IMU messages in all)."""
    heartbeat = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=1))
    records = [struct.pack(">Q", T0_US) + bytes(heartbeat)]
    counts = {1: 0, 2: 0}
    for k in range(IMU_HZ * SECONDS):
        system = 1 if k % 10 == 0 else 2
        counts[system] += 1
        t_us = 1_000_000 + k * 1_000_000 // IMU_HZ
        records.append(struct.pack(">Q", T0_US + 2_000 + t_us) + _packet(system, counts[system], t_us))
    path.write_bytes(b"".join(records))
    return counts[1], counts[1] + counts[2]


def test_a_tlog_whose_imu_data_mostly_did_not_reach_the_loop_is_flagged_in_the_batch_summary(tmp_path: Path) -> None:
    log = tmp_path / "two_vehicles.tlog"
    used, decodable = write_two_vehicle_tlog(log)
    alone = replay(log, tmp_path / "alone.mcap", FuserConfig(), progress=None).inputs
    assert (alone.imu_used, alone.imu_decodable) == (used, decodable)
    assert alone.warning() is not None  # replay LOG warns

    (result,) = run_batch([log], tmp_path / "out", FuserConfig(), jobs=1)
    assert result.ok and result.input_warning == alone.warning()
    lines = batch.format_summary([result])
    assert f"only {used:,} of {decodable:,} decodable IMU messages" in "\n".join(lines)
    assert any("other_sender=" in line for line in lines)  # and why
