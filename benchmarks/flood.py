"""Floods against a live MavlinkSource on loopback: memory stays bounded, the real samples keep coming.

    python benchmarks/flood.py               # four floods of 60 s each, then the same against pymavlink alone
    python benchmarks/flood.py --seconds 10 --no-peer

Each flood runs in fresh processes: a receiver (``MavlinkSource("udpin:127.0.0.1:PORT")`` with
the default link settings, polled as ``bingham-fuser run`` polls it), a vehicle sending real
HIGHRES_IMU at 400 Hz (and HEARTBEAT at 1 Hz) stamped with its send time on the machine's
monotonic clock, and a flooder sending as fast as it can for ``--seconds``:

* ``unknown_ids``: frames with message ids in no dialect, ten to a datagram;
* ``sources``: valid HIGHRES_IMU from 300,000 distinct (system, component, instance) senders, one per datagram;
* ``datagrams40``: datagrams of 40 valid HIGHRES_IMU frames from another system;
* ``random``: datagrams of 1-1400 random bytes.

The receiver reports its RSS after 3 s of real data alone and again after the flood (and a 2 s
drain), and the latency of every real sample received during the flood (receive time minus send
time). The peer is pymavlink alone (``mavutil.mavlink_connection`` and ``recv_msg``, one message per
call, as the drivers read links before): the same floods, the same measurements, in the same run.
Targets (issue 12): RSS growth under 50 MB, real samples' p99 latency under 20 ms.
"""

from __future__ import annotations

import argparse
import gc
import json
import multiprocessing as mp
import os
import socket
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
os.environ.setdefault("MAVLINK20", "1")

VEHICLE = (1, 1)
IMU_HZ = 400.0
WARM_S, DRAIN_S = 3.0, 2.0
FLOODS = ("unknown_ids", "sources", "datagrams40", "random")


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def vehicle(port: int, until: float) -> None:
    """The real vehicle: HIGHRES_IMU at 400 Hz stamped with its monotonic send time, HEARTBEAT at 1 Hz."""
    from pymavlink.dialects.v20 import common

    mav = common.MAVLink(None, srcSystem=VEHICLE[0], srcComponent=VEHICLE[1])
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    next_hb, k, start = 0.0, 0, time.monotonic()
    while (now := time.monotonic()) < until:
        data = b""
        if now >= next_hb:
            data += bytes(common.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mav))
            mav.seq = (mav.seq + 1) % 256
            next_hb = now + 1.0
        msg = common.MAVLink_highres_imu_message(time.monotonic_ns() // 1000, 0, 0, -9.81, 0, 0, 0, 0.2, 0, 0.4, 0, 0, 0, 0, 0x1FF, 0)
        data += bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        out.sendto(data, ("127.0.0.1", port))
        k += 1
        time.sleep(max(0.0, start + k / IMU_HZ - time.monotonic()))


def flood_pool(kind: str, rng: np.random.Generator) -> list[bytes]:
    """The datagrams a flooder cycles through."""
    from pymavlink.dialects.v20 import ardupilotmega as apm
    from pymavlink.dialects.v20 import common

    if kind == "unknown_ids":
        unknown = [i for i in range(1 << 16, (1 << 16) + 60_000) if i not in apm.mavlink_map]
        frames = [bytes([0xFD, 20, 0, 0, i & 0xFF, 7, 1]) + i.to_bytes(3, "little") + rng.bytes(22) for i in unknown]
        return [b"".join(frames[j : j + 10]) for j in range(0, len(frames), 10)]
    if kind == "random":
        return [rng.bytes(int(rng.integers(1, 1401))) for _ in range(4_000)]
    if kind == "sources":
        ids = [(s, c, i) for s in range(2, 256) for c in range(1, 256) for i in range(5)][:300_000]
    else:
        ids = [(2, 1, 0)] * 4_000
    mav = common.MAVLink(None)
    frames = []
    for k, (system, component, instance) in enumerate(ids):
        mav.srcSystem, mav.srcComponent, mav.seq = system, component, k % 256
        msg = common.MAVLink_highres_imu_message(1_000_000 + k, 0, 0, -9.81, 0, 0, 0, 0.2, 0, 0.4, 0, 0, 0, 0, 0x1FF, instance)
        frames.append(bytes(msg.pack(mav)))
    if kind == "sources":
        return frames
    return [b"".join(frames[j : j + 40]) for j in range(0, len(frames), 40)]


def flooder(port: int, kind: str, start: float, until: float, report: mp.Queue) -> None:
    pool = flood_pool(kind, np.random.default_rng(1))
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
    time.sleep(max(0.0, start - time.monotonic()))
    sent = nbytes = 0
    addr = ("127.0.0.1", port)
    while time.monotonic() < until:
        for data in pool[sent % len(pool) : sent % len(pool) + 256]:
            try:
                out.sendto(data, addr)
            except OSError:  # ENOBUFS: the kernel is full; a flooder does not care
                pass
            sent += 1
            nbytes += len(data)
    report.put({"datagrams": sent, "MB": round(nbytes / 1e6, 1)})


def receiver(port: int, peer: bool, flood_start: float, flood_end: float, report: mp.Queue) -> None:
    """The fuser's side: poll the link, measure the real samples' latency, RSS before and after."""
    if peer:
        from pymavlink import mavutil

        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")

        def poll() -> list[int]:
            out = []
            for _ in range(1024):  # the drivers' old loop: one message per call, at most 1024 per poll
                msg = conn.recv_msg()
                if msg is None:
                    break
                if msg.get_type() == "HIGHRES_IMU" and msg.get_srcSystem() == VEHICLE[0]:
                    out.append(msg.time_usec * 1000)
            if not out:
                conn.select(0.05)
            return out
    else:
        from drivers import MavlinkSource

        source = MavlinkSource(f"udpin:127.0.0.1:{port}")

        def poll() -> list[int]:
            return [s.t_ns for s in source.poll(0.05)]

    gc.collect()
    latencies, real, rss_before = [], 0, None
    end = flood_end + DRAIN_S
    while (now := time.monotonic()) < end:
        if rss_before is None and now >= flood_start:
            gc.collect()
            rss_before = rss_mb()
        for t_ns in poll():
            if flood_start <= t_ns / 1e9 < flood_end:
                latencies.append(time.monotonic_ns() - t_ns)
                real += 1
    gc.collect()
    lat = np.array(latencies, dtype=float) / 1e6
    stats = {} if peer else {k: v for k, v in sorted(source.stats.items()) if v}
    report.put({
        "rss_before_MB": rss_before, "rss_after_MB": rss_mb(), "real": real,
        "p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "p99_ms": float(np.percentile(lat, 99)) if lat.size else float("nan"), "stats": stats,
    })


def run_flood(kind: str, seconds: float, peer: bool) -> dict:
    ctx = mp.get_context("spawn")
    port = free_port()
    report, flood_report = ctx.Queue(), ctx.Queue()
    start = time.monotonic() + 4.0 + WARM_S  # spawn and imports, then the vehicle alone
    end = start + seconds
    procs = [
        ctx.Process(target=receiver, args=(port, peer, start, end, report)),
        ctx.Process(target=vehicle, args=(port, end + DRAIN_S)),
        ctx.Process(target=flooder, args=(port, kind, start, end, flood_report)),
    ]
    for p in procs:
        p.start()
    result = report.get(timeout=seconds + 120)
    result |= flood_report.get(timeout=30)
    for p in procs:
        p.join(30)
    result["real_fraction"] = result["real"] / (IMU_HZ * seconds)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="length of each flood (default: 60)")
    parser.add_argument("--no-peer", action="store_true", help="skip the pymavlink-alone runs")
    parser.add_argument("--only", choices=FLOODS, action="append", help="run only this flood (repeatable)")
    args = parser.parse_args()
    rows = []
    for kind in args.only or FLOODS:
        for peer in (False,) if args.no_peer else (False, True):
            r = run_flood(kind, args.seconds, peer)
            rows.append((kind, "pymavlink alone" if peer else "MavlinkSource", r))
            print(json.dumps({"flood": kind, "peer": peer, **r}), flush=True)
    print(f"\n{args.seconds:.0f} s per flood; RSS of the receiving process; latency of the real 400 Hz samples received during the flood\n")
    print("| flood | receiver | sent | RSS before -> after (MB) | growth (MB) | real samples received | p50 (ms) | p99 (ms) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for kind, who, r in rows:
        growth = r["rss_after_MB"] - r["rss_before_MB"]
        print(f"| {kind} | {who} | {r['datagrams']:,} datagrams, {r['MB']:,} MB | {r['rss_before_MB']:.0f} -> {r['rss_after_MB']:.0f} | "
              f"{growth:+.0f} | {100 * r['real_fraction']:.0f}% | {r['p50_ms']:.1f} | {r['p99_ms']:.1f} |")


if __name__ == "__main__":
    main()
