"""Telemetry logs (.tlog) shaped like real ArduPilot ground-station logs, deterministic from a seed.

Built from what real logs of multi-IMU ArduPilot copters show (issue 13, notes/dependencies.md):

* three IMUs, each its own message type, units and clock: RAW_IMU (``time_usec``), SCALED_IMU2
  and SCALED_IMU3 (``time_boot_ms``), each at its own rate: 2.7-3.8 Hz over a telemetry radio,
  50-400 Hz on a companion computer's wire;
* ATTITUDE, GPS_RAW_INT (Unix ``time_usec``, as ArduPilot stamps it) and GLOBAL_POSITION_INT at
  3-4 Hz (their companion rates in the second variant); SYS_STATUS; HEARTBEATs from the autopilot
  and from the ground station (MAVLink 1, MAV_TYPE_GCS), and the radio's own RADIO_STATUS;
* bursts of PARAM_VALUE (the parameter download after connecting, and again after the reboot);
* ArduPilot-only messages: AHRS, AHRS2, AHRS3, EKF_STATUS_REPORT, VIBRATION, SIMSTATE;
* a reboot: the autopilot silent for seconds, then its boot clock and sequence numbers start again;
* the radio: packets lost (sequence gaps), hundreds of packets damaged (bad CRC, a wrong length
  byte), garbage runs between packets (logged as records and unlogged), a few record times that
  are nonsense, a last record cut short; receive times from the ground station's own clock
  (drifting 40 ppm against the autopilot's), with a SiK-like latency: 20 ms air frames plus a
  queueing delay, packets of one frame arriving together.

Every IMU, attitude and position value comes from :func:`drivers.sim.simulate`'s truth (measured
IMU, true attitude), so a decoded log can be checked against it. Nothing here uses the project's
encoders or decoders: messages are packed with pymavlink directly.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as apm

from drivers.sim import Flight, SimConfig, simulate

AUTOPILOT = (1, 1)
GCS = (255, 190)
RADIO = (51, 68)  # SiK radios report as system 51 ('3'), component 68 ('D')
IMU_TYPES = ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3")
G_MG = 1000.0 / 9.80665
UNIX_START_S = 1_700_000_000.0
HOME = (-35.3632621, 149.1652374, 584.0)  # ArduPilot SITL's default home (CMAC)


@dataclass(frozen=True)
class TlogShape:
    """What to build: rates per message type (Hz), the link, the faults, all deterministic from ``seed``."""

    seed: int = 0
    duration_s: float = 120.0
    boot_at_start_s: float = 95.0
    """The autopilot has been up this long when the log starts."""
    rates_hz: dict[str, float] = field(default_factory=lambda: {
        "RAW_IMU": 3.3, "SCALED_IMU2": 2.8, "SCALED_IMU3": 3.7, "ATTITUDE": 3.6, "GPS_RAW_INT": 3.2,
        "GLOBAL_POSITION_INT": 3.4, "SYS_STATUS": 1.0, "AHRS": 2.0, "AHRS2": 2.0, "AHRS3": 2.0,
        "EKF_STATUS_REPORT": 1.0, "VIBRATION": 1.0, "SIMSTATE": 2.0,
    })
    rate_jitter: float = 0.1
    """Each interval between two messages of a type varies by up to this fraction."""
    param_count: int = 900
    param_burst_hz: float = 40.0
    reboot_at_s: float | None = 70.0
    reboot_silent_s: float = 8.0
    boot_after_reboot_s: float = 3.0
    """The autopilot's boot clock when it speaks again."""
    radio: bool = True
    """SiK-like latency with 20 ms air frames; False: a wire (0.5 ms plus a little)."""
    drift_ppm: float = 40.0
    loss_fraction: float = 0.02
    bad_crc: int = 300
    bad_length: int = 20
    garbage_runs: int = 150
    absurd_times: int = 5
    truncated_end: bool = True


COMPANION = TlogShape(
    seed=1, duration_s=20.0, rates_hz={
        "RAW_IMU": 400.0, "SCALED_IMU2": 200.0, "SCALED_IMU3": 50.0, "ATTITUDE": 50.0, "GPS_RAW_INT": 5.0,
        "GLOBAL_POSITION_INT": 10.0, "SYS_STATUS": 1.0, "AHRS": 10.0, "AHRS2": 10.0, "AHRS3": 10.0,
        "EKF_STATUS_REPORT": 5.0, "VIBRATION": 5.0, "SIMSTATE": 10.0,
    }, rate_jitter=0.02, param_count=300, param_burst_hz=500.0, reboot_at_s=12.0, reboot_silent_s=3.0,
    radio=False, drift_ppm=20.0, loss_fraction=0.002, bad_crc=40, bad_length=5, garbage_runs=20, absurd_times=2,
)
"""A companion computer wired to the autopilot: IMU at 50-400 Hz, little damage."""


@dataclass
class BuiltTlog:
    """The log and what was written into it, for checking a reader against."""

    path: Path
    flight: Flight
    imu_intact: int = 0
    """IMU packets written undamaged (with a sane or an absurd record time)."""
    imu_damaged: int = 0
    imu_lost: int = 0
    """IMU packets the radio lost (never written)."""
    autopilot_missing: int = 0
    """Autopilot packets lost or damaged: the gaps its sequence numbers show."""
    records: int = 0
    absurd_time_records: int = 0
    imu_sent: dict[str, list[tuple[int, tuple[int, int, int]]]] = field(default_factory=dict)
    """Per IMU type, (sender time ns, raw gyro in mrad/s) of every IMU message sent, written or not."""


def up_intervals(shape: TlogShape) -> list[tuple[float, float, float]]:
    """(start, end, boot clock at start) of each stretch the autopilot talks, in log time (s)."""
    if shape.reboot_at_s is None:
        return [(0.0, shape.duration_s, shape.boot_at_start_s)]
    back = shape.reboot_at_s + shape.reboot_silent_s
    return [(0.0, shape.reboot_at_s, shape.boot_at_start_s), (back, shape.duration_s, shape.boot_after_reboot_s)]


def true_attitude_at(built: BuiltTlog, shape: TlogShape, boot_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's attitude (w, x, y, z) at autopilot boot-clock times ``boot_ns`` (the clock of its IMUs and
    ATTITUDE, which restarts at the reboot), from the 400 Hz truth the messages were made from, and the log
    time (s) of each; NaN outside every stretch the autopilot talked."""
    boot_s = np.asarray(boot_ns, dtype=float) * 1e-9
    t = np.full(boot_s.shape, np.nan)
    for start, end, boot0 in up_intervals(shape):
        inside = (boot_s >= boot0) & (boot_s < boot0 + end - start)
        t[inside] = boot_s[inside] - boot0 + start
    index = np.clip(np.round(np.nan_to_num(t) * 400.0).astype(int), 0, len(built.flight.t_ns) - 1)
    q = built.flight.q_true[index]
    q[np.isnan(t)] = np.nan
    return q, t


class _Sender:
    """One MAVLink sender with its own sequence numbers, packing in the order of sending."""

    def __init__(self, ids: tuple[int, int], mavlink1: bool = False) -> None:
        self.mav = apm.MAVLink(None, srcSystem=ids[0], srcComponent=ids[1])
        self.mavlink1 = mavlink1

    def pack(self, msg: apm.MAVLink_message) -> bytes:
        data = bytes(msg.pack(self.mav, force_mavlink1=self.mavlink1))
        self.mav.seq = (self.mav.seq + 1) % 256
        return data


def _schedule(rng: np.random.Generator, rate_hz: float, start_s: float, end_s: float, jitter: float) -> list[float]:
    times, t = [], start_s + rng.uniform(0.0, 1.0 / rate_hz)
    while t < end_s:
        times.append(t)
        t += rng.uniform(1.0 - jitter, 1.0 + jitter) / rate_hz
    return times


def _milli(v: np.ndarray, scale: float) -> tuple[int, int, int]:
    return tuple(int(max(-32767, min(32767, round(c * scale)))) for c in v)  # type: ignore[return-value]


def _euler(q: np.ndarray) -> tuple[float, float, float]:
    w, x, y, z = q
    return (
        math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
        math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))),
        math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)),
    )


class _Builder:
    def __init__(self, shape: TlogShape, flight: Flight) -> None:
        self.shape = shape
        self.flight = flight
        self.rng = np.random.default_rng(shape.seed)
        self.t0_s = flight.t_ns[0] / 1e9
        self.gcs, self.radio = _Sender(GCS, mavlink1=True), _Sender(RADIO)
        self.autopilot = _Sender(AUTOPILOT)
        self.events: list[tuple[float, int, str, _Sender, apm.MAVLink_message, int]] = []
        """(log time, order, kind, sender, message, sender time ns), packed in time order once all are known."""
        self.imu_sent: dict[str, list[tuple[int, tuple[int, int, int]]]] = {m: [] for m in IMU_TYPES}

    def add(self, t_s: float, kind: str, msg: apm.MAVLink_message, sender: _Sender | None = None, sender_ns: int = 0) -> None:
        self.events.append((t_s, len(self.events), kind, sender or self.autopilot, msg, sender_ns))

    def index(self, t_s: float) -> int:
        return min(len(self.flight.t_ns) - 1, max(0, int(round(t_s * 400.0))))

    def vehicle_messages(self, start: float, end: float, boot0: float) -> None:
        s, f, rng = self.shape, self.flight, self.rng
        boot = lambda t: boot0 + (t - start)  # noqa: E731 - the autopilot's boot clock at log time t
        for t in np.arange(start, end, 1.0):
            self.add(float(t), "HEARTBEAT", apm.MAVLink_heartbeat_message(2, 3, 81, 0, 3, 3))
        for k in range(s.param_count):  # the parameter download the ground station asks for
            t = start + 0.5 + k / s.param_burst_hz
            if t < end:
                msg = apm.MAVLink_param_value_message(f"PARAM_{k:04d}".encode(), float(k) * 0.5, 9, s.param_count, k)
                self.add(t, "PARAM_VALUE", msg)
        bias = {"RAW_IMU": 0.0, "SCALED_IMU2": 0.002, "SCALED_IMU3": -0.003}  # each IMU its own small gyro offset (rad/s)
        for kind, rate in s.rates_hz.items():
            for t in _schedule(rng, rate, start, end, s.rate_jitter):
                i = self.index(t)
                b_us = int(round(boot(t) * 1e6))
                b_ms = b_us // 1000
                if kind in IMU_TYPES:
                    acc = _milli(f.accel_m_s2[i], G_MG)
                    gyro = _milli(f.gyro_rad_s[i] + bias[kind], 1000.0)
                    mag = _milli(f.mag_true_gauss[i], 1000.0)
                    if kind == "RAW_IMU":
                        msg = apm.MAVLink_raw_imu_message(b_us, *acc, *gyro, *mag, 0, 4500)
                        sender_ns = b_us * 1000
                    else:
                        msg = getattr(apm, f"MAVLink_{kind.lower()}_message")(b_ms, *acc, *gyro, *mag, 4500)
                        sender_ns = b_ms * 1_000_000
                    self.imu_sent[kind].append((sender_ns, gyro))
                    self.add(t, kind, msg, sender_ns=sender_ns)
                    continue
                roll, pitch, yaw = _euler(f.q_true[i])
                lat, lon = int(HOME[0] * 1e7), int(HOME[1] * 1e7)
                msg = {
                    "ATTITUDE": lambda: apm.MAVLink_attitude_message(b_ms, roll, pitch, yaw, *f.gyro_true_rad_s[i]),
                    "GPS_RAW_INT": lambda: apm.MAVLink_gps_raw_int_message(
                        int((UNIX_START_S + t) * 1e6), 3, lat, lon, int(HOME[2] * 1000), 90, 140, 12, 4500, 14,
                        int(HOME[2] * 1000) + 21000, 800, 1200, 300, 0, 0),
                    "GLOBAL_POSITION_INT": lambda: apm.MAVLink_global_position_int_message(
                        b_ms, lat, lon, int(HOME[2] * 1000), 0, 3, -2, 1, int(math.degrees(yaw) % 360 * 100)),
                    "SYS_STATUS": lambda: apm.MAVLink_sys_status_message(0x3FFFFF, 0x3FFFFF, 0x3FFFFF, 420, 12400, 1500, 78, 0, 0, 0, 0, 0, 0),
                    "AHRS": lambda: apm.MAVLink_ahrs_message(0.001, -0.002, 0.0005, 0.9, 1.0, 0.01, 0.02),
                    "AHRS2": lambda: apm.MAVLink_ahrs2_message(roll, pitch, yaw, HOME[2], lat, lon),
                    "AHRS3": lambda: apm.MAVLink_ahrs3_message(roll, pitch, yaw, HOME[2], lat, lon, 0, 0, 0, 0),
                    "EKF_STATUS_REPORT": lambda: apm.MAVLink_ekf_status_report_message(0x3FF, 0.1, 0.2, 0.1, 0.05, 0.0, 0.0),
                    "VIBRATION": lambda: apm.MAVLink_vibration_message(b_us, 3.1, 2.9, 4.2, 0, 0, 0),
                    "SIMSTATE": lambda: apm.MAVLink_simstate_message(roll, pitch, yaw, *f.accel_true_m_s2[i], *f.gyro_true_rad_s[i], lat, lon),
                }[kind]()
                self.add(t, kind, msg)

    def ground_messages(self) -> None:
        for t in np.arange(0.3, self.shape.duration_s, 1.0):  # the ground station's own HEARTBEAT, MAVLink 1
            self.add(float(t), "HEARTBEAT_GCS", apm.MAVLink_heartbeat_message(6, 8, 192, 0, 4, 3), self.gcs)
            if self.shape.radio:
                self.add(float(t) + 0.05, "RADIO_STATUS", apm.MAVLink_radio_status_message(180, 175, 90, 40, 42, 3, 0), self.radio)

    def receive_times(self) -> list[tuple[float, str, bytes, int]]:
        """Events in arrival order with the ground station's receive time (its clock, in s since UNIX_START_S)."""
        s, rng = self.shape, self.rng
        out = []
        last = 0.0
        intervals = up_intervals(self.shape)
        reboot = intervals[-1][0] if len(intervals) > 1 else math.inf
        for t, _, kind, sender, msg, sender_ns in sorted(self.events, key=lambda e: (e[0], e[1])):
            if sender is self.autopilot and t >= reboot:  # the autopilot's sequence starts again after its reboot
                reboot, sender.mav.seq = math.inf, 0
            packet = sender.pack(msg)
            if s.radio and not kind.endswith("_GCS"):
                latency = 0.025 + rng.gamma(2.0, 0.012)
                arrival = math.ceil((t + latency) / 0.02) * 0.02 + rng.uniform(0.0, 0.002)  # the radio's air frames
            else:
                arrival = t + 0.0005 + rng.exponential(0.0003)
            arrival = max(arrival, last)  # one link: first in, first out
            last = arrival
            out.append((arrival * (1.0 + s.drift_ppm * 1e-6), kind, packet, sender_ns))
        return out


def build_tlog(path: str | Path, shape: TlogShape = TlogShape()) -> BuiltTlog:
    """Write the .tlog of ``shape`` to ``path`` (deterministic for ``shape.seed``)."""
    path = Path(path)
    flight = simulate(SimConfig(seed=shape.seed, duration_s=shape.duration_s + 1.0, imu_rate_hz=400.0, dropout_probability=0.0))
    b = _Builder(shape, flight)
    for start, end, boot0 in up_intervals(shape):
        b.vehicle_messages(start, end, boot0)
    b.ground_messages()
    arrivals = b.receive_times()
    rng = b.rng
    n = len(arrivals)
    lost = set(rng.choice(n, int(shape.loss_fraction * n), replace=False).tolist())
    kept = [k for k in range(n) if k not in lost]
    pick = rng.permutation(kept)
    cuts = np.cumsum([shape.bad_crc, shape.bad_length, shape.absurd_times])
    bad_crc, bad_length, absurd = set(pick[: cuts[0]].tolist()), set(pick[cuts[0] : cuts[1]].tolist()), set(pick[cuts[1] : cuts[2]].tolist())
    garbage_after = set(rng.choice(kept, shape.garbage_runs, replace=False).tolist())
    built = BuiltTlog(path, flight, imu_sent=b.imu_sent)
    with open(path, "wb") as f:
        for k, (arrival, kind, packet, _) in enumerate(arrivals):
            is_imu = kind in IMU_TYPES
            from_autopilot = kind not in ("HEARTBEAT_GCS", "RADIO_STATUS")
            if k in lost:
                built.imu_lost += is_imu
                built.autopilot_missing += from_autopilot
                continue
            stamp = struct.pack(">Q", int(round((UNIX_START_S + arrival) * 1e6)))
            data = bytearray(packet)
            if k in bad_crc:  # a bit error in the payload or the CRC
                data[int(rng.integers(10, len(data)))] ^= 1 << int(rng.integers(0, 8))
            elif k in bad_length:  # a bit error in the length byte: the record's framing breaks
                data[1] ^= 1 << int(rng.integers(0, 8))
            if k in absurd:  # the record time itself is damaged (a high byte)
                stamp = bytes([stamp[0] ^ 0x40]) + stamp[1:]
                built.absurd_time_records += 1
            cut = shape.truncated_end and k == len(arrivals) - 1
            if cut:  # the ground station stopped mid-write
                data = data[: len(data) // 2]
            damaged = k in bad_crc or k in bad_length or cut
            built.imu_intact += is_imu and not damaged
            built.imu_damaged += is_imu and damaged
            built.autopilot_missing += from_autopilot and damaged
            f.write(stamp + bytes(data))
            built.records += 1
            if k in garbage_after:  # radio noise the ground station logged as a record, or wrote unframed
                junk = rng.integers(0, 256, int(rng.integers(5, 200)), dtype=np.uint8).tobytes()
                f.write((stamp if rng.random() < 0.67 else b"") + junk)
    return built
