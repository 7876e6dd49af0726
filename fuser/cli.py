"""``bingham-fuser``: the command line.

    bingham-fuser sim                      simulated vehicle -> loop -> zenoh + sim.mcap
    bingham-fuser run --mavlink udpin:0.0.0.0:14550 --can socketcan:can0
    bingham-fuser replay flight.mcap -o fused.mcap
    bingham-fuser listen
    bingham-fuser report fused.mcap -o report/
    bingham-fuser import trial.hdf5 -o trial.mcap   (BROAD trial or PX4 .ulg -> MCAP)

Every setting can also come from a TOML file (``--config``); flags win.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from contextlib import ExitStack
from pathlib import Path
from typing import Any, Sequence

from drivers.scenarios import SCENARIOS
from fuser import batch
from fuser.config import FuserConfig, load_config

__all__ = ["main"]

log = logging.getLogger("bingham_fuser")


def _common(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("common options")
    g.add_argument("--config", metavar="FILE.toml", help="read settings from a TOML file (flags override it)")
    g.add_argument("--vehicle", help="vehicle name in the zenoh keys bingham_fuser/<vehicle>/... (default: sim)")
    g.add_argument("--rate", type=float, dest="rate_hz", metavar="HZ", help="estimates per second (default: 100)")
    g.add_argument("--no-mag", action="store_true", help="6-D fusion: ignore magnetometers")
    g.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")


def _zenoh(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT", help="listen endpoint (repeatable; default tcp/127.0.0.1:7447)")
    g.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT", help="router or peer to connect to (repeatable)")
    g.add_argument("--no-zenoh", action="store_true", help="do not publish")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bingham-fuser",
        description="Streaming quaternion Bingham-filter attitude fuser: MAVLink / DroneCAN in, zenoh and MCAP out.",
        epilog="Run 'bingham-fuser COMMAND --help' for a command's options.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("sim", help="fly the simulated vehicle through the live loop (no drone needed)",
                       description="Fly the built-in simulated multirotor (hover, turns, aggressive manoeuvres, a flip) "
                                   "through the real decoders and the live loop; publish on zenoh, record MCAP with the truth, "
                                   "and print the error against the truth.")
    _common(p)
    _zenoh(p)
    p.add_argument("--duration", type=float, default=60.0, metavar="S", help="seconds of flight (default: 60)")
    p.add_argument("--scenario", choices=("full",) + tuple(SCENARIOS), default="full",
                   help="full: the whole programme for --duration (hover, turns, aggressive, a flip); "
                        + "; ".join(f"{k}: {v}" for k, v in SCENARIOS.items()).replace("%", "%%"))  # argparse %-formats help
    p.add_argument("--speed", type=float, default=1.0, metavar="X", help="1 = real time, 10 = ten times faster, 0 = as fast as possible (default: 1)")
    p.add_argument("--transport", choices=("mavlink", "dronecan"), default="mavlink", help="what the vehicle speaks (default: mavlink)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default: 0)")
    p.add_argument("--imu-rate", type=float, default=400.0, metavar="HZ", help="IMU rate (default: 400)")
    p.add_argument("-o", "--record", default="sim.mcap", metavar="FILE.mcap", help="record inputs, truth and estimates here (default: sim.mcap; '' to disable)")
    g = p.add_argument_group("send to a live fuser", "be the vehicle on the far end of a real link instead of running the loop here")
    g.add_argument("--send", metavar="CONN", help="send the flight's MAVLink in real time to this pymavlink connection, e.g. udpout:127.0.0.1:14550")
    g.add_argument("--send-can", metavar="IFACE:CHANNEL", help="send its DroneCAN frames to this python-can bus")
    g.add_argument("--truth", metavar="FILE", help="write the true attitude at the sender's times (.npz or .mcap)")
    g.add_argument("--start-at", metavar="UNIX_TIME|+S", help="send the first sample at this Unix time (keeps several senders in step), "
                   "or S seconds after the flight is ready (default: +0.2); the time chosen is printed")
    g.add_argument("--outage", metavar="AT:SECONDS", help="fault: send nothing for SECONDS from AT seconds into the flight")
    g.add_argument("--garbage", type=float, default=0.0, metavar="PER_S", help="fault: random bytes per second on MAVLink (frames per second on CAN)")

    p = sub.add_parser("run", help="fuse live MAVLink and/or DroneCAN input",
                       description="Fuse live input. MAVLink CONN is anything pymavlink opens: udpin:0.0.0.0:14550, "
                                   "tcp:127.0.0.1:5760, /dev/ttyUSB0 (with --baud). CAN is INTERFACE:CHANNEL for python-can: "
                                   "socketcan:can0, slcan:/dev/ttyACM0, virtual:test.")
    _common(p)
    _zenoh(p)
    p.add_argument("--mavlink", action="append", default=[], metavar="CONN", help="MAVLink connection (repeatable)")
    p.add_argument("--baud", type=int, default=57600, help="serial baud rate for MAVLink (default: 57600)")
    p.add_argument("--can", action="append", default=[], metavar="IFACE:CHANNEL", help="CAN bus with DroneCAN nodes (repeatable)")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="CAN bitrate where the interface needs one (default: 1000000)")
    p.add_argument("--attitude-sigma", type=float, dest="attitude_sigma_deg", metavar="DEG", help="also fuse the autopilot's attitude with this noise")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("-o", "--record", metavar="FILE.mcap", help="record inputs and estimates (in a separate process)")

    p = sub.add_parser("replay", help="replay a recorded MCAP or .tlog through the loop, as fast as possible",
                       description="Replay a log (MCAP recorded by bingham-fuser, or a MAVLink .tlog) through the same loop on "
                                   "a virtual clock and write inputs and estimates to a new MCAP. Same log, same bytes. "
                                   "Many logs: --out-dir DIR, in parallel processes (--jobs) or on a Dask cluster (--dask).")
    _common(p)
    batch.add_replay_arguments(p)

    p = sub.add_parser("import", help="convert a BROAD trial (.hdf5) or a PX4 ULog (.ulg) into a replayable MCAP",
                       description="Encode a real log's IMU (and a PX4 log's EKF2 attitude) as MAVLink, decode it with the "
                                   "project's driver and record an MCAP with the truth / reference attitude on /truth/pose. "
                                   "Needs h5py (BROAD) or pyulog (PX4): pip install 'bingham-fuser[import]'. See fuser/importers.py.")
    _common(p)
    p.add_argument("source", help="BROAD trial .hdf5 or PX4 .ulg")
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap", help="MCAP to write")
    p.add_argument("--format", choices=("broad", "px4"), help="input format (default: from the file extension)")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="skip the first S seconds (default: 0)")
    p.add_argument("--duration", type=float, metavar="S", help="keep only S seconds (default: all)")
    p.add_argument("--config-out", metavar="FILE.toml", help="TOML with the measured reference field, for replay --config "
                   "(default: OUT.toml beside the MCAP; '' to skip)")

    p = sub.add_parser("listen", help="print the estimates arriving on zenoh", description="Subscribe to bingham_fuser/<vehicle>/attitude and print each estimate.")
    _common(p)
    _zenoh(p)
    p.add_argument("--json", action="store_true", help="print the raw JSON payloads")
    p.add_argument("--count", type=int, metavar="N", help="stop after N estimates")

    p = sub.add_parser("report", help="plots and a summary table of a fused log", description="Write PNG plots (attitude against the truth or the "
                       "autopilot, error, uncertainty) and print a summary table. Needs matplotlib (pip install 'bingham-fuser[report]').")
    _common(p)
    p.add_argument("log", help="an MCAP written by sim, run or replay")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="folder for the PNGs (default: report)")
    return parser


def _config(args: argparse.Namespace) -> FuserConfig:
    overrides: dict[str, Any] = {"vehicle": args.vehicle, "rate_hz": args.rate_hz}
    if args.no_mag:
        overrides["use_mag"] = False
    for name in ("zenoh_listen", "zenoh_connect"):
        if getattr(args, name, None):
            overrides[name] = tuple(getattr(args, name))
    if getattr(args, "attitude_sigma_deg", None) is not None:
        overrides["attitude_sigma_deg"] = args.attitude_sigma_deg
    return load_config(args.config, **overrides)


def _publisher(stack: ExitStack, config: FuserConfig, args: argparse.Namespace):
    if getattr(args, "no_zenoh", False):
        return None
    from fuser.publish import ZenohPublisher, zenoh_config

    pub = ZenohPublisher(zenoh_config(list(config.zenoh_listen), list(config.zenoh_connect)), config.vehicle)
    stack.callback(pub.close)
    return pub


def _cmd_sim(args: argparse.Namespace, config: FuserConfig) -> int:
    from drivers.scenarios import flight as make_flight
    from fuser.pipeline import Pipeline
    from fuser.record import McapRecorder, RecorderProcess
    from fuser.simulate import run_sim

    if args.send or args.send_can:
        from fuser.sender import run_sender

        return run_sender(args, _stop_on_signal())
    with ExitStack() as stack:
        pub = _publisher(stack, config, args)
        rec = None
        if args.record:
            # paced runs record in a separate process, like live ones; a full-speed run
            # would outpace it, so it records in-process and loses nothing
            recorder = McapRecorder if args.speed <= 0 else RecorderProcess
            rec = recorder(args.record, metadata={"source": "bingham-fuser sim", "scenario": args.scenario, "seed": str(args.seed)})
            stack.callback(rec.close)
        outputs = _estimate_sinks(pub, rec)
        pipeline = Pipeline(config, [rec.write_sample] if rec else [], outputs)
        stop = _stop_on_signal()
        flight = make_flight(args.scenario, args.seed, args.imu_rate, args.duration)
        seconds = (flight.t_ns[-1] - flight.t_ns[0]) / 1e9
        print(f"sim: {args.scenario} flight, {seconds:.0f} s at {'full speed' if args.speed <= 0 else f'{args.speed:g}x'}"
              + (f", publishing on bingham_fuser/{config.vehicle}/attitude" if pub else "")
              + (f", recording {args.record}" if rec else ""), file=sys.stderr)
        run = run_sim(pipeline, flight, args.transport, args.speed, [rec.write_truth] if rec else [], stop)
    print(f"sim: {run.samples} samples -> {run.estimates} estimates in {run.wall_s:.1f} s")
    if args.record:
        _print_scores(args.record)
    return 0


def _estimate_sinks(pub: Any, rec: Any) -> list:
    """Where each estimate goes: zenoh first, so a subscriber never waits for the recorder's
    serialisation (measured: +0.1 ms on the publish latency the other way round), then MCAP."""
    return [s for s in (pub.publish_estimate if pub else None, rec.write_estimate if rec else None) if s]


def _cmd_run(args: argparse.Namespace, config: FuserConfig) -> int:
    from drivers.sources import DroneCanSource, MavlinkSource
    from fuser.live import LiveRunner
    from fuser.pipeline import Pipeline
    from fuser.record import RecorderProcess

    if not args.mavlink and not args.can:
        print("run: give at least one --mavlink CONN or --can IFACE:CHANNEL", file=sys.stderr)
        return 2
    with ExitStack() as stack:
        sources: dict[str, Any] = {}
        for conn in args.mavlink:
            options = {"baud": args.baud} if conn.startswith("/dev/") or conn.upper().startswith("COM") else {}
            sources[f"mavlink:{conn}"] = stack.enter_context(MavlinkSource(conn, **options))
        for spec in args.can:
            interface, _, channel = spec.partition(":")
            if not channel:
                print(f"run: --can wants INTERFACE:CHANNEL, got {spec!r}", file=sys.stderr)
                return 2
            extra = {} if interface in ("virtual", "socketcan") else {"bitrate": args.bitrate}
            sources[f"can:{spec}"] = stack.enter_context(DroneCanSource(interface=interface, channel=channel, **extra))
        pub = _publisher(stack, config, args)
        rec = None
        if args.record:
            rec = RecorderProcess(args.record, metadata={"source": "bingham-fuser run"})
            stack.callback(rec.close)
        outputs = _estimate_sinks(pub, rec)
        pipeline = Pipeline(config, [rec.write_sample] if rec else [], outputs)
        status_sinks = [s for s in (rec.write_status if rec else None, (lambda t, d: pub.publish_status(d)) if pub else None) if s]

        def health() -> dict:
            out: dict[str, Any] = {}
            if rec is not None:
                out["recorder"] = {"alive": rec.alive, "dropped": rec.dropped}
            if pub is not None:
                out["publisher"] = {"errors": pub.errors, "subscribed": pub.has_subscribers}
            return out

        runner = LiveRunner(pipeline, sources, status_sinks, health)
        _stop_on_signal(runner.stop)
        print(f"run: fusing {', '.join(sources)} at {config.rate_hz:g} Hz; Ctrl-C to stop", file=sys.stderr)
        status = runner.run(args.duration)
    print(f"run: {status['estimates']} estimates; loop {status['loop']}; latency {status['latency']}")
    return 0


def _cmd_replay(args: argparse.Namespace, config: FuserConfig) -> int:
    from fuser.replay import replay

    if batch.is_batch(args):
        return batch.command(args, config)
    summary = replay(args.log[0], args.output, config)
    print(f"replay: {summary.samples} samples -> {summary.estimates} estimates in {summary.seconds:.2f} s "
          f"({summary.samples_per_s:,.0f} samples/s); {args.output}")
    if summary.counters:
        print("counters: " + ", ".join(f"{k}={v}" for k, v in sorted(summary.counters.items())))
    _print_scores(args.output)
    return 0


def _cmd_import(args: argparse.Namespace, config: FuserConfig) -> int:  # noqa: ARG001
    from fuser.importers import detect_format, import_log

    try:
        fmt = args.format or detect_format(args.source)
    except ValueError as exc:
        print(f"import: {exc}", file=sys.stderr)
        return 2
    module = {"broad": "h5py", "px4": "pyulog"}[fmt]
    try:
        __import__(module)
    except ImportError:
        print(f"import: reading {fmt} logs needs the '{module}' package: pip install 'bingham-fuser[import]' "
              f"(or pip install {module})", file=sys.stderr)
        return 2
    cfg_out = str(Path(args.output).with_suffix(".toml")) if args.config_out is None else (args.config_out or None)
    s = import_log(args.source, args.output, fmt, args.start, args.duration, cfg_out)
    print(f"import: {s.imu} IMU + {s.attitude} attitude messages through MAVLink, {s.truth} reference attitudes -> {s.path}")
    print(f"reference field (N, E, D gauss): {s.mag_field_ned_gauss}" + (f"; replay with --config {s.config_path}" if s.config_path else ""))
    refused = {k: v for k, v in s.decoder_stats.items() if k != "accepted" and v}
    if refused:
        print(f"decoder refused: {refused}")
    return 0


def _cmd_listen(args: argparse.Namespace, config: FuserConfig) -> int:
    from fuser.publish import listen, zenoh_config

    # a listener connects to the fuser's endpoint unless told otherwise
    connect = list(config.zenoh_connect) or list(config.zenoh_listen)
    listen(zenoh_config(listen=[], connect=connect), config.vehicle, json_output=args.json, count=args.count)
    return 0


def _cmd_report(args: argparse.Namespace, config: FuserConfig) -> int:
    try:
        from fuser.report import write_report
    except ImportError as exc:
        print(f"report needs matplotlib: pip install 'bingham-fuser[report]' ({exc})", file=sys.stderr)
        return 2
    for line in write_report(args.log, Path(args.output)):
        print(line)
    return 0


def _print_scores(path: str) -> None:
    from fuser.report import score_log

    for line in score_log(path):
        print(line)


def _stop_on_signal(callback=None):
    """Make Ctrl-C / SIGTERM stop the run cleanly (files closed, footer written)."""
    stopped = {"flag": False}

    def handler(signum, frame):  # noqa: ARG001
        stopped["flag"] = True
        if callback is not None:
            callback()

    if threading.current_thread() is threading.main_thread():  # signals can only be caught there
        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)
    return lambda: stopped["flag"]


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)], format="%(levelname)s %(name)s: %(message)s")
    try:
        config = _config(args)
    except (OSError, ValueError) as exc:
        print(f"bingham-fuser: {exc}", file=sys.stderr)
        return 2
    commands = {"sim": _cmd_sim, "run": _cmd_run, "replay": _cmd_replay, "listen": _cmd_listen, "report": _cmd_report,
                "import": _cmd_import}
    return commands[args.command](args, config)


if __name__ == "__main__":
    sys.exit(main())
