#!/usr/bin/env python3
"""Minimal subscriber for bingham-fuser estimates: the Python standard library and zenoh only.

    pip install eclipse-zenoh
    python examples/subscribe.py                                  # fuser on this machine (default endpoint)
    python examples/subscribe.py --connect tcp/192.168.1.10:7447  # a fuser or a router elsewhere
    python examples/subscribe.py --vehicle '*' --raw --count 10   # any vehicle, raw JSON, stop after 10

Each estimate on ``bingham_fuser/<vehicle>/attitude`` is a JSON object (see
fuser/IO.md): ``t_ns`` (tick time, ns), ``q_wxyz`` (body FRD -> world NED,
w first), ``M`` and ``Z`` (the Bingham posterior), ``uncertainty_deg``,
``euler_deg`` (roll, pitch, yaw) and ``counters``.
"""

import argparse
import json
import queue
import sys

import zenoh


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", action="append", help="zenoh endpoint to connect to (repeatable); default tcp/127.0.0.1:7447")
    parser.add_argument("--vehicle", default="*", help="vehicle name, or * for all (default)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many estimates (0: never)")
    parser.add_argument("--raw", action="store_true", help="print the JSON payload as it arrives")
    args = parser.parse_args()

    # Explicit endpoints, scouting off: multicast discovery is often unavailable (containers, some networks).
    config = zenoh.Config.from_json5(json.dumps({
        "mode": "peer",
        "connect": {"endpoints": args.connect or ["tcp/127.0.0.1:7447"]},
        "listen": {"endpoints": []},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }))
    arrived: "queue.Queue[tuple[str, bytes]]" = queue.Queue()
    with zenoh.open(config) as session:
        session.declare_subscriber(f"bingham_fuser/{args.vehicle}/attitude",
                                   lambda s: arrived.put((str(s.key_expr), s.payload.to_bytes())))
        print("subscribed", flush=True)
        n = 0
        try:
            while not args.count or n < args.count:
                key, payload = arrived.get()
                try:  # anyone on the network can put on the key: skip what is not an estimate
                    est = json.loads(payload)
                    roll, pitch, yaw = (float(a) for a in est["euler_deg"])
                    line = (f"{key}  t={int(est['t_ns']) / 1e9:.6f} s  roll={roll:.2f}  pitch={pitch:.2f}  yaw={yaw:.2f} deg"
                            f"  +/-{float(est['uncertainty_deg']):.2f} deg")
                except (ValueError, TypeError, KeyError, RecursionError) as exc:
                    print(f"skipped a payload on {key} that is not an estimate: {type(exc).__name__}", file=sys.stderr, flush=True)
                    continue
                print(payload.decode() if args.raw else line, flush=True)
                n += 1
        except KeyboardInterrupt:
            pass


if __name__ == "__main__":
    main()
