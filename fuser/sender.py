"""A simulated autopilot on a real link: the simulated flight, paced to the wall clock, sent as bytes and frames.

Where ``bingham-fuser sim`` runs the simulated vehicle *inside* the fuser,
this is the vehicle on the other end of a link: it sends the flight's MAVLink
bytes to a pymavlink connection (``udpout:127.0.0.1:14550``, ``tcp:...``)
and/or its DroneCAN frames to a python-can bus, each IMU tick at its time
from ``start_at``, and writes the truth (sender time, true quaternion) to a
file so that whatever the fuser publishes can be scored against it (the
estimates' ``sensor_t_ns`` is on this sender's clock).

Faults for tests: a link outage (nothing sent for ``outage_s`` seconds from
``outage_at_s`` into the flight) and garbage (random bytes between MAVLink
packets, random extended-id frames on CAN) at a given rate.

    bingham-fuser sim --scenario hover --send udpout:127.0.0.1:14550 --truth truth.npz
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from drivers.sim import Flight, dronecan_stream, mavlink_stream
from fuser.errors import FuserError

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink's first import (see drivers.sources)

__all__ = ["SendFaults", "SendReport", "send_flight", "write_truth"]

_SLEEP_SLICE_S = 0.05
"""Longest single sleep while waiting, so a stop request is seen quickly."""


@dataclass(frozen=True)
class SendFaults:
    """Faults injected on the link (times in seconds from the flight's first sample)."""

    outage_at_s: float | None = None
    outage_s: float = 0.0
    garbage_per_s: float = 0.0
    """MAVLink: random bytes per second, sent as datagrams of their own between packets; CAN: random frames per second."""
    seed: int = 0

    def in_outage(self, t_s: float) -> bool:
        return self.outage_at_s is not None and self.outage_at_s <= t_s < self.outage_at_s + self.outage_s


@dataclass
class SendReport:
    """What went out: the numbers a test checks the fuser's counters against."""

    start_at: float
    """Unix time of the flight's first sample."""
    ticks: int = 0
    imu_sent: int = 0
    """IMU samples sent (the simulator's own dropouts and the outage are not sent)."""
    imu_withheld: int = 0
    """IMU samples not sent because of the outage."""
    mavlink_bytes: int = 0
    can_frames: int = 0
    garbage_bytes: int = 0
    garbage_frames: int = 0
    max_late_ms: float = 0.0
    """Worst lateness of a tick against its due time (pacing quality)."""
    stopped: bool = False


def write_truth(flight: Flight, path: str | Path, rate_hz: float = 100.0) -> None:
    """The true attitude at the sender's times: ``.npz`` (arrays ``t_ns``, ``q_wxyz``, every IMU tick) or ``.mcap`` (``/truth/pose``)."""
    path = Path(path)
    if path.suffix == ".mcap":
        from fuser.record import McapRecorder

        every = max(1, round((len(flight.t_ns) / max((flight.t_ns[-1] - flight.t_ns[0]) / 1e9, 1e-9)) / rate_hz))
        with McapRecorder(path, metadata={"source": "bingham-fuser sim --send"}) as rec:
            for t, q in zip(flight.t_ns[::every].tolist(), flight.q_true[::every].tolist()):
                rec.write_truth(t, tuple(q))
    else:
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, t_ns=flight.t_ns, q_wxyz=flight.q_true)
        os.replace(tmp, path)  # a reader never sees half a file


def send_flight(
    flight: Flight,
    mavlink: str | None = None,
    can_bus: Any = None,
    start_at: float | None = None,
    faults: SendFaults = SendFaults(),
    should_stop: Callable[[], bool] = lambda: False,
    can_node_id: int = 10,
) -> SendReport:
    """Send ``flight`` in real time: its first IMU tick at Unix time ``start_at`` (default: now).

    ``mavlink`` is a pymavlink connection string (the bytes of each tick go out
    in one write, i.e. one datagram on UDP); ``can_bus`` a python-can bus.
    Several senders given the same ``start_at`` stay in step (two IMUs on one
    vehicle). A tick that is due while the sender is behind goes out at once.
    """
    if mavlink is None and can_bus is None:
        raise ValueError("send_flight needs a MAVLink connection string and/or a CAN bus")
    import can  # noqa: PLC0415 - only the senders that use CAN pay for it
    from pymavlink import mavutil  # noqa: PLC0415

    conn = mavutil.mavlink_connection(mavlink, dialect="common", source_system=1) if mavlink else None
    rng = np.random.default_rng(faults.seed)
    start_at = time.time() if start_at is None else start_at
    report = SendReport(start_at=start_at)
    # the monotonic clock paces; the Unix time only anchors the start (shared between processes)
    start_mono = time.monotonic() + (start_at - time.time())
    t0 = int(flight.t_ns[0])
    mav_ticks = mavlink_stream(flight) if conn is not None else None
    can_ticks = dronecan_stream(flight, can_node_id) if can_bus is not None else None
    garbage_due = 0.0
    last_t_s = 0.0
    try:
        for k in range(len(flight.t_ns)):
            mav = next(mav_ticks) if mav_ticks is not None else None
            frames = next(can_ticks)[2] if can_ticks is not None else None
            t_s = (int(flight.t_ns[k]) - t0) / 1e9
            due = start_mono + t_s
            while (wait := due - time.monotonic()) > 0:
                if should_stop():
                    break
                time.sleep(min(wait, _SLEEP_SLICE_S))
            if should_stop():
                report.stopped = True
                break
            report.max_late_ms = max(report.max_late_ms, (time.monotonic() - due) * 1e3)
            report.ticks += 1
            valid = bool(flight.imu_valid[k])
            if faults.in_outage(t_s):
                report.imu_withheld += valid
                last_t_s = t_s
                continue
            report.imu_sent += valid
            garbage_due += faults.garbage_per_s * (t_s - last_t_s)
            last_t_s = t_s
            n_garbage = int(garbage_due)
            garbage_due -= n_garbage
            if conn is not None:
                if n_garbage:
                    conn.write(rng.integers(0, 256, n_garbage, dtype=np.uint8).tobytes())
                    report.garbage_bytes += n_garbage
                data = mav[2]
                if data:
                    conn.write(data)
                    report.mavlink_bytes += len(data)
            if can_bus is not None:
                if n_garbage:
                    for _ in range(n_garbage):
                        can_bus.send(can.Message(arbitration_id=int(rng.integers(0, 1 << 29)), is_extended_id=True,
                                                 data=rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8).tobytes()))
                    report.garbage_frames += n_garbage
                for frame in frames:
                    can_bus.send(frame)
                report.can_frames += len(frames)
    finally:
        if conn is not None:
            conn.close()
    return report


def run_sender(args: Any, flight: Flight, stop: Callable[[], bool]) -> int:
    """``bingham-fuser sim --send ...``: write the truth of ``flight`` (made from the sim flags), send it.

    The command line has checked the flags (fuser.cli): only the sender's own act here.
    """
    if args.truth:
        write_truth(flight, args.truth)
    at, seconds = args.outage or (None, 0.0)  # parsed by the command line as (AT, SECONDS)
    faults = SendFaults(at, seconds, args.garbage, args.seed)
    bus = None
    if args.send_can:
        import can

        interface, _, channel = args.send_can.partition(":")
        try:
            bus = can.Bus(interface=interface, channel=channel)
        except (can.CanError, OSError, ValueError) as e:
            raise FuserError(f"cannot open CAN bus {args.send_can}: {e}") from e
    start = args.start_at or "+0.2"
    start_at = time.time() + float(start[1:]) if start.startswith("+") else float(start)
    seconds = (flight.t_ns[-1] - flight.t_ns[0]) / 1e9
    print(f"sim --send: {args.scenario} flight, {seconds:.1f} s at {args.imu_rate:g} Hz to "
          f"{', '.join(x for x in (args.send, args.send_can) if x)}; first sample at {start_at:.6f}", file=sys.stderr, flush=True)
    if start_at < time.time():
        print(f"sim --send: started {time.time() - start_at:.3f} s late", file=sys.stderr, flush=True)
    try:
        report = send_flight(flight, args.send, bus, start_at, faults, stop)
    except OSError as e:  # the link would not open, or went away while sending
        raise FuserError(f"cannot send to {args.send}: {e.strerror or e}") from e
    finally:
        if bus is not None:
            bus.shutdown()
    print(json.dumps(asdict(report)), flush=True)
    return 0
