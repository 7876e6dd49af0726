"""Decoder throughput: MAVLink from bytes and DroneCAN from frames, against pymavlink's bare parse loop.

Run: python benchmarks/bench_drivers.py [--seconds 20]
Input is the simulator's PX4-style stream (HIGHRES_IMU at 400 Hz, ATTITUDE_QUATERNION
at 25 Hz, HEARTBEAT at 1 Hz) as one byte string, and its DroneCAN frames. Each figure is the best of
five runs; the overhead is the driver's time per message over pymavlink's.
"""

from __future__ import annotations

import argparse
import platform
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mav_common

from drivers import DroneCanDecoder, MavlinkDecoder
from drivers.sim import SimConfig, dronecan_stream, mavlink_stream, simulate

REPEATS = 5


def best_rate(run: Callable[[], int]) -> tuple[float, int]:
    """Messages per second of the fastest of REPEATS runs, and the message count."""
    best = float("inf")
    count = 0
    for _ in range(REPEATS):
        start = time.perf_counter()
        count = run()
        best = min(best, time.perf_counter() - start)
    return count / best, count


def bare_pymavlink(data: bytes) -> int:
    parser = mav_common.MAVLink(None)
    parser.robust_parsing = True
    return len(parser.parse_buffer(data) or [])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated flight length")
    args = parser.parse_args()

    flight = simulate(SimConfig(duration_s=args.seconds, dropout_probability=0.0))
    data = b"".join(chunk for _, _, chunk in mavlink_stream(flight))
    short = simulate(SimConfig(duration_s=min(args.seconds, 5.0), dropout_probability=0.0))
    frames = [f for _, _, fs in dronecan_stream(short) for f in fs]

    bare, n_bare = best_rate(lambda: bare_pymavlink(data))
    def mav_run() -> int:
        decoder = MavlinkDecoder()
        return len(decoder.feed(data)) + decoder.stats["ignored"]  # samples, and the HEARTBEATs it reads past

    mav, n_mav = best_rate(mav_run)

    def can_run() -> int:
        decoder = DroneCanDecoder()
        return sum(len(decoder.feed(f)) for f in frames)

    can_rate, n_can = best_rate(can_run)
    assert n_mav == n_bare, (n_mav, n_bare)

    print(f"python {platform.python_version()} on {platform.machine()}, one core, best of {REPEATS}")
    print(f"{'path':<44} {'messages':>9} {'msg/s':>10}")
    print(f"{'pymavlink parse_buffer (bare, reference)':<44} {n_bare:>9} {bare:>10,.0f}")
    print(f"{'MavlinkDecoder.feed (parse+validate+sample)':<44} {n_mav:>9} {mav:>10,.0f}")
    print(f"{'DroneCanDecoder.feed (transfers)':<44} {n_can:>9} {can_rate:>10,.0f}")
    print(f"{'DroneCAN frames through DroneCanDecoder':<44} {len(frames):>9} {can_rate * len(frames) / n_can:>10,.0f}")
    print(f"MAVLink driver overhead over bare pymavlink: {bare / mav - 1:+.1%} time per message "
          f"(driver/bare throughput ratio {mav / bare:.2f})")


if __name__ == "__main__":
    main()
