"""A DataFlash log whose time starts again: two boots in one file (logs joined, a board that rebooted while its
log went on), or one damaged time.

ArduPilot stamps every record with the time since boot (``TimeUS``); a second boot starts that clock again. The
import puts records in time order, so two boots in one file were interleaved into one flight that never was (each
IMU then fed samples of two attitudes, and exit 0). The import now takes the boot with the most IMU records and
counts every record of the others (``other_boot_records``), and a single damaged time is not a boot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fuser.dataflash import read_dataflash

from dataflash_writer import DataFlashWriter

IMU_HZ = 50
INSTANCES = (0, 1, 2)


def _writer() -> DataFlashWriter:
    w = DataFlashWriter()
    w.declare(76, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    w.declare(86, "ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF")
    return w


def _boot(w: DataFlashWriter, start_us: int, seconds: float, gyro_z: float, damaged_at: int | None = None) -> int:
    """One boot's IMU records (three instances, interleaved) and ATT at 10 Hz; each boot's gyro reads its own
    ``gyro_z`` so that the imported samples tell which boot they came from. ``damaged_at``: that sample's time
    is written 5 s early (a damaged record). Returns the number of records written."""
    n = round(seconds * IMU_HZ)
    for k in range(n):
        t_us = start_us + k * 1_000_000 // IMU_HZ
        for i in INSTANCES:
            stamp = t_us - 5_000_000 if k == damaged_at and i == 0 else t_us + 150 * i
            w.write("IMU", TimeUS=stamp, I=i, GyrX=0.0, GyrY=0.0, GyrZ=gyro_z, AccX=0.0, AccY=0.0, AccZ=-9.81,
                    EG=0, EA=0, T=40.0, GH=1, AH=1, GHz=1000, AHz=1000)
        if k % 5 == 0:
            w.write("ATT", TimeUS=t_us + 70, DesRoll=0, Roll=1.0, DesPitch=0, Pitch=0, DesYaw=0, Yaw=10.0, ErrRP=0.0,
                    ErrYaw=0.0, AEKF=3)
    return n * len(INSTANCES) + (n + 4) // 5


def test_a_second_boot_is_not_interleaved_with_the_first_the_longer_is_imported(tmp_path: Path) -> None:
    """A 4-s boot, then a 10-s boot whose clock starts again (1.234 ms off the first's grid): the 10-s boot is the
    flight, the 4-s one is counted."""
    w = _writer()
    short = _boot(w, 3_000_000, 4.0, gyro_z=0.1)
    _boot(w, 2_001_234, 10.0, gyro_z=-0.2)
    path = tmp_path / "two_boots.bin"
    path.write_bytes(bytes(w.data))
    data = read_dataflash(path)
    assert [s.instance for s in data.imus] == list(INSTANCES)
    for imu in data.imus:
        assert len(imu.t_ns) == 10 * IMU_HZ
        assert np.all(imu.gyro[:, 2] == np.float32(-0.2))  # only the second boot's samples
        assert np.all(np.diff(imu.t_ns) > 0)
    assert len(data.ref_t_ns) == 10 * IMU_HZ // 5 and data.ref_t_ns[0] == 2_001_234_000 + 70_000
    assert data.skipped == {"other_boots": 1, "other_boot_records": short}


def test_the_first_boot_wins_when_it_is_the_longer(tmp_path: Path) -> None:
    w = _writer()
    _boot(w, 3_000_000, 6.0, gyro_z=0.1)
    short = _boot(w, 2_500_000, 2.0, gyro_z=-0.2)
    path = tmp_path / "reboot_at_the_end.bin"
    path.write_bytes(bytes(w.data))
    data = read_dataflash(path)
    assert all(np.all(imu.gyro[:, 2] == np.float32(0.1)) and len(imu.t_ns) == 6 * IMU_HZ for imu in data.imus)
    assert data.skipped == {"other_boots": 1, "other_boot_records": short}


def test_one_damaged_time_is_not_a_boot(tmp_path: Path) -> None:
    """A single record stamped 5 s early mid-log: placed where it says, as before; nothing else changes."""
    w = _writer()
    _boot(w, 3_000_000, 8.0, gyro_z=0.1, damaged_at=200)
    path = tmp_path / "one_bad_time.bin"
    path.write_bytes(bytes(w.data))
    data = read_dataflash(path)
    assert [len(imu.t_ns) for imu in data.imus] == [8 * IMU_HZ] * len(INSTANCES)
    assert data.skipped == {}
