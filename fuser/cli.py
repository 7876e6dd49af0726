"""``bingham-fuser``: the command line.

    bingham-fuser sim                      simulated vehicle -> loop -> zenoh + sim.mcap
    bingham-fuser run --mavlink udpin:0.0.0.0:14550 --can socketcan:can0
    bingham-fuser replay flight.mcap -o fused.mcap
    bingham-fuser listen
    bingham-fuser report fused.mcap -o report/
    bingham-fuser import trial.hdf5 -o trial.mcap   (BROAD trial, PX4 .ulg or ArduPilot .bin -> MCAP)

Every fusion setting can also come from a TOML file (``--config``); flags win.

Each subcommand's options are declared in one place (``_add_<command>``),
built from small option groups (``_fusion_options``, ``_zenoh_publish_options``,
...) attached only to the subcommands where they act. Options that do nothing
in the mode chosen are refused; an option that overrides another is warned
about.

Errors: every expected failure (a missing file, a malformed connection string,
an unknown CAN interface, a port in use, a bad configuration, a missing
optional package, a file that is not a log) ends the command with one line on
stderr that says what to fix, and exit code 2 (bad usage: the command as given
cannot run) or 1 (it started and failed). ``--verbose`` adds the traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import re
import signal
import sys
import threading
import traceback
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterable, NoReturn, Sequence

from drivers.base import SourceError
from drivers.scenarios import SCENARIOS
from drivers.sim import MAX_RATE_HZ
from fuser import argtypes, batch
from fuser.config import FuserConfig, load_config
from fuser.errors import EXIT_RUNTIME, EXIT_USAGE, FuserError, UsageError, check_log_file, require_package
from fuser.outputs import add_options as add_output_options
from fuser.outputs import mavlink_connection
from fuser.streams import stdout_gone

__all__ = ["main"]

log = logging.getLogger("bingham_fuser")

PROG = "bingham-fuser"
SIM_DURATION_S = 60.0
"""Length of ``sim --scenario full`` unless ``--duration`` says otherwise."""
MAX_SPEED = 1000.0
"""``sim --speed``'s most: a thousand times real time, beyond what the loop keeps up with (it then runs behind)."""
MAX_GARBAGE_PER_S = 1_000_000.0
"""``sim --garbage``'s most: 1 MB a second of noise on MAVLink, more than any telemetry link carries (frames: a 1 Mbit/s
CAN bus carries at most about 15,000 a second)."""
DEFAULT_BAUD = 57600
DEFAULT_BITRATE = 1_000_000
CAN_WITHOUT_BITRATE = ("virtual", "socketcan", "udp_multicast")
"""python-can interfaces that take no bitrate (the bus's is set outside the program)."""
EXIT_INTERRUPTED = 130


# --------------------------------------------------------------------------- parser


class _Parser(argparse.ArgumentParser):
    """argparse, with a usage error as one line (and exit code 2) instead of the usage text.

    Abbreviated options are off: a prefix would be taken for the longer option
    it starts (``import --config x`` for ``--config-out x``, writing x).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, allow_abbrev=False, **kwargs)

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bingham-fuser")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _can_bus(text: str) -> str:
    """argparse type of ``--can`` / ``--send-can``: INTERFACE:CHANNEL with an interface python-can knows."""
    import can

    interface, _, channel = text.partition(":")
    if not channel:
        raise argparse.ArgumentTypeError(f"{text!r}: expected INTERFACE:CHANNEL, e.g. socketcan:can0 or slcan:/dev/ttyACM0")
    if interface not in can.VALID_INTERFACES:
        raise argparse.ArgumentTypeError(f"unknown CAN interface {interface!r}: python-can knows {', '.join(sorted(can.VALID_INTERFACES))}")
    return text


def _verbosity(p: argparse.ArgumentParser) -> None:
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug); tracebacks of errors")


def _config_file(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE.toml", help="read settings from a TOML file (flags override it)")


def _fusion_options(p: argparse.ArgumentParser) -> None:
    """What the fusion loop and model read: sim, run, replay."""
    g = p.add_argument_group("fusion")
    g.add_argument("--rate", type=float, dest="rate_hz", metavar="HZ", help="filter ticks per second (default: 100); between ticks an estimate at every IMU sample")
    g.add_argument("--no-mag", action="store_true", help="6-D fusion: ignore magnetometers")
    g.add_argument("--no-attitude", action="store_true", help="never fuse the autopilot's attitude messages (by default they "
                   "are fused while the IMU arrives too slowly to carry the attitude: [fuser.attitude] mode)")


def _vehicle_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", help="vehicle name in the zenoh keys bingham_fuser/<vehicle>/... (default: sim for sim, vehicle for "
                                     "run; listen hears every vehicle)")


def _zenoh_publish_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT", help="listen endpoint (repeatable; default tcp/127.0.0.1:7447)")
    g.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT", help="router or peer to connect to (repeatable)")
    g.add_argument("--no-zenoh", action="store_true", help="do not publish")


def _zenoh_subscribe_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="the fuser (or a router) to connect to (repeatable; default: the fuser's listen endpoint, tcp/127.0.0.1:7447)")
    g.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help="the fuser's --zenoh-listen endpoint, connected to when --zenoh-connect is not given")


def _link(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("MAVLink link", "which vehicle to fuse and how its frames are authenticated (see drivers/README.md)")
    g.add_argument("--system", type=int, metavar="ID", help="vehicle system id (default: the first autopilot heard)")
    g.add_argument("--component", type=int, metavar="ID", help="vehicle component id (default: that autopilot's)")
    g.add_argument("--any-sender", action="store_true", help="use every sender's data, not only the first autopilot's")
    g.add_argument("--signing-key-file", metavar="FILE", help="MAVLink 2 signing key (32 raw bytes, or a passphrase hashed "
                   "with SHA-256 as MAVProxy does): unsigned and wrongly signed frames are refused")
    g.add_argument("--dialect", metavar="NAME", help="pymavlink dialect (default: ardupilotmega)")


def _live_loop_options(p: argparse.ArgumentParser) -> None:
    """The options of a subcommand that runs the live loop (``sim``, ``run``): fusion, vehicle, zenoh, outputs."""
    _verbosity(p)
    _config_file(p)
    _fusion_options(p)
    _vehicle_option(p)
    _zenoh_publish_options(p)
    add_output_options(p)


def _add_sim(sub: Any) -> None:
    p = sub.add_parser("sim", help="fly the simulated vehicle through the live loop (no drone needed)",
                       description="Fly the built-in simulated multirotor (hover, turns, aggressive manoeuvres, a flip) "
                                   "through the real decoders and the live loop; publish on zenoh, record MCAP with the truth, "
                                   "and print the error against the truth.")
    p.set_defaults(handler=_cmd_sim)
    _live_loop_options(p)
    p.add_argument("--scenario", choices=("full",) + tuple(SCENARIOS), default="full",
                   help="full: the whole programme for --duration (hover, turns, aggressive, a flip); "
                        + "; ".join(f"{k}: {v}" for k, v in SCENARIOS.items()).replace("%", "%%"))  # argparse %-formats help
    p.add_argument("--duration", type=argtypes.seconds, metavar="S", help=f"seconds of flight with --scenario full (default: {SIM_DURATION_S:g})")
    p.add_argument("--speed", type=argtypes.number(0, MAX_SPEED, " times real time"), metavar="X",
                   help="1 = real time, 10 = ten times faster, 0 = as fast as possible (default: 1)")
    p.add_argument("--transport", choices=("mavlink", "dronecan"), help="what the vehicle speaks (default: mavlink)")
    p.add_argument("--seed", type=argtypes.integer(0), default=0, help="simulation seed (default: 0)")
    p.add_argument("--imu-rate", type=argtypes.number(1, MAX_RATE_HZ, " Hz"), default=400.0, metavar="HZ", help="IMU rate (default: 400)")
    p.add_argument("-o", "--record", metavar="FILE.mcap", help="record inputs, truth and estimates here (default: sim.mcap; '' to disable)")
    g = p.add_argument_group("send to a live fuser", "be the vehicle on the far end of a real link instead of running the loop here "
                             "(the fusion, zenoh and recording options then do not apply)")
    g.add_argument("--send", metavar="CONN", help="send the flight's MAVLink in real time to this pymavlink connection, e.g. udpout:127.0.0.1:14550")
    g.add_argument("--send-can", type=_can_bus, metavar="IFACE:CHANNEL", help="send its DroneCAN frames to this python-can bus")
    g.add_argument("--truth", metavar="FILE", help="write the true attitude at the sender's times (.npz or .mcap)")
    g.add_argument("--start-at", type=argtypes.start_time, metavar="UNIX_TIME|+S", help="send the first sample at this Unix time (keeps several senders "
                   "in step), or S seconds after the flight is ready (default: +0.2); the time chosen is printed")
    g.add_argument("--outage", type=argtypes.outage, metavar="AT:SECONDS", help="fault: send nothing for SECONDS from AT seconds into the flight")
    g.add_argument("--garbage", type=argtypes.number(0, MAX_GARBAGE_PER_S, " a second"), metavar="PER_S",
                   help="fault: random bytes per second on MAVLink (frames per second on CAN)")


def _add_run(sub: Any) -> None:
    p = sub.add_parser("run", help="fuse live MAVLink and/or DroneCAN input",
                       description="Fuse live input. MAVLink CONN is anything pymavlink opens: udpin:0.0.0.0:14550, "
                                   "tcp:127.0.0.1:5760, /dev/ttyUSB0 (with --baud). CAN is INTERFACE:CHANNEL for python-can: "
                                   "socketcan:can0, slcan:/dev/ttyACM0, virtual:test.")
    p.set_defaults(handler=_cmd_run)
    _live_loop_options(p)
    _link(p)
    g = p.add_argument_group("inputs")
    g.add_argument("--mavlink", action="append", default=[], type=mavlink_connection, metavar="CONN", help="MAVLink connection (repeatable)")
    g.add_argument("--baud", type=argtypes.integer(1), metavar="BAUD",
                   help=f"serial baud rate of the serial --mavlink connections (default: {DEFAULT_BAUD})")
    g.add_argument("--can", action="append", default=[], type=_can_bus, metavar="IFACE:CHANNEL", help="CAN bus with DroneCAN nodes (repeatable)")
    g.add_argument("--bitrate", type=argtypes.integer(1),
                   help=f"CAN bitrate for interfaces that set one, e.g. slcan (default: {DEFAULT_BITRATE})")
    g.add_argument("--request-rate", type=float, dest="request_rate_hz", metavar="HZ",
                   help="ask each MAVLink vehicle to stream its IMU and attitude at HZ (GNSS at most 10 Hz), as a ground "
                        "station does, repeated until they come (default: only listen; drivers/stream_request.py)")
    p.add_argument("--attitude-sigma", type=float, dest="attitude_sigma_deg", metavar="DEG", help="also fuse the autopilot's attitude with this noise")
    p.add_argument("--duration", type=argtypes.seconds, metavar="S", help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("-o", "--record", metavar="FILE.mcap", help="record inputs and estimates (in a separate process); "
                   "an existing file is kept unless --overwrite is given")
    p.add_argument("--overwrite", action="store_true", help="let --record replace an existing file")


def _add_replay(sub: Any) -> None:
    p = sub.add_parser("replay", help="replay a recorded MCAP, a .tlog, or a log import reads, through the loop, as fast as possible",
                       description="Replay a log (MCAP recorded by bingham-fuser, a MAVLink .tlog, or an ArduPilot DataFlash log, "
                                   "PX4 ULog or BROAD trial, imported on the way with the reference field the import finds unless "
                                   "the configuration sets one) through the same loop on "
                                   "a virtual clock and write inputs and estimates to a new MCAP. Same log, same bytes. A damaged "
                                   "MCAP replays every chunk that can be read, and says what it skipped. Many logs: --out-dir DIR, "
                                   "in parallel processes (--jobs) or on a Dask cluster (--dask).")
    p.set_defaults(handler=_cmd_replay, vehicle=None)  # no zenoh here: the vehicle name does not apply
    _verbosity(p)
    _config_file(p)
    _fusion_options(p)
    _link(p)
    batch.add_replay_arguments(p)


def _add_import(sub: Any) -> None:
    p = sub.add_parser("import", help="convert a BROAD trial (.hdf5), a PX4 ULog (.ulg) or an ArduPilot DataFlash log (.bin) into a replayable MCAP",
                       description="Encode a real log's IMU, magnetometer and GNSS (and the autopilot's attitude) as MAVLink, decode "
                                   "them with the project's driver and record an MCAP with the truth / reference attitude on /truth/pose. "
                                   "Needs h5py (BROAD) or pyulog (PX4): pip install 'bingham-fuser[import]'. See fuser/importers.py.")
    p.set_defaults(handler=_cmd_import)
    _verbosity(p)
    p.add_argument("source", help="BROAD trial .hdf5, PX4 .ulg or ArduPilot .bin")
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap", help="MCAP to write")
    p.add_argument("--format", choices=("broad", "px4", "dataflash"), help="input format (default: from the file extension)")
    p.add_argument("--start", type=partial(argtypes.seconds, positive=False), default=0.0, metavar="S", help="skip the first S seconds (default: 0)")
    p.add_argument("--duration", type=argtypes.seconds, metavar="S", help="keep only S seconds (default: all)")
    p.add_argument("--config-out", metavar="FILE.toml", help="TOML with the measured reference field, for replay --config "
                   "(default: OUT.toml beside the MCAP; '' to skip)")


def _add_listen(sub: Any) -> None:
    p = sub.add_parser("listen", help="print the estimates arriving on zenoh", description="Subscribe to bingham_fuser/<vehicle>/attitude "
                       "and print each estimate.")
    p.set_defaults(handler=_cmd_listen, rate_hz=None, no_mag=False)  # the config's fusion settings do not apply here
    _verbosity(p)
    _config_file(p)
    _vehicle_option(p)
    _zenoh_subscribe_options(p)
    p.add_argument("--json", action="store_true", help="print the raw JSON payloads")
    p.add_argument("--count", type=argtypes.integer(1), metavar="N", help="stop after N estimates")


def _add_report(sub: Any) -> None:
    p = sub.add_parser("report", help="plots and a summary table of a fused log", description="Write PNG plots (attitude against the truth or the "
                       "autopilot, error, uncertainty) and print a summary table. Needs matplotlib (pip install 'bingham-fuser[report]').")
    p.set_defaults(handler=_cmd_report)
    _verbosity(p)
    p.add_argument("log", help="an MCAP written by sim, run or replay")
    p.add_argument("-o", "--output", default="report", metavar="DIR", help="folder for the PNGs (default: report)")


SUBCOMMANDS: tuple[Callable[[Any], None], ...] = (_add_sim, _add_run, _add_replay, _add_listen, _add_report, _add_import)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description="Streaming quaternion Bingham-filter attitude fuser: MAVLink / DroneCAN in, zenoh and MCAP out.",
        epilog="Run 'bingham-fuser COMMAND --help' for a command's options. Exit codes: 0 done, 1 failed while running, "
               "2 bad usage (options, configuration, input files, missing package).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(sub)
    return parser


# --------------------------------------------------------------------------- checks between options


def _warn(message: str) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def _given(args: argparse.Namespace, options: dict[str, str]) -> list[str]:
    """The flags among ``options`` (flag -> dest) that were given (not None, not False, not empty)."""
    return [flag for flag, dest in options.items() if getattr(args, dest, None) not in (None, False, [], "")]


def _list(flags: list[str]) -> str:
    return f"{', '.join(flags)} {'acts' if len(flags) == 1 else 'act'}"


def _check_sim(args: argparse.Namespace) -> None:
    """Refuse the options that would do nothing in the mode chosen; resolve the defaults that depend on it."""
    if args.send or args.send_can:
        idle = _given(args, {"--config": "config", "--rate": "rate_hz", "--no-mag": "no_mag", "--vehicle": "vehicle",
                             "--zenoh-listen": "zenoh_listen", "--zenoh-connect": "zenoh_connect", "--no-zenoh": "no_zenoh",
                             "--record": "record", "--transport": "transport"})
        if idle:
            raise UsageError(f"sim --send: {_list(idle)} on a fuser running here, and --send runs none "
                             "(the fuser is on the far end of the link): drop them")
        if args.speed not in (None, 1.0):
            raise UsageError("sim --send: a live link runs in real time; --speed must be 1")
    else:
        idle = _given(args, {"--truth": "truth", "--start-at": "start_at", "--outage": "outage", "--garbage": "garbage"})
        if idle:
            raise UsageError(f"sim: {_list(idle)} only with --send or --send-can")
    if args.scenario != "full" and args.duration is not None:
        _warn(f"--scenario {args.scenario} is a flight of fixed length: it overrides --duration {args.duration:g} "
              "(--duration sets the length of --scenario full)")
    args.duration = SIM_DURATION_S if args.duration is None else args.duration
    args.speed = 1.0 if args.speed is None else args.speed
    args.transport = args.transport or "mavlink"
    args.garbage = args.garbage or 0.0
    args.record = "sim.mcap" if args.record is None else args.record


def _is_serial(conn: str) -> bool:
    return conn.startswith("/dev/") or bool(re.fullmatch(r"COM\d+", conn, re.I))


def _check_run(args: argparse.Namespace) -> None:
    if not args.mavlink and not args.can:
        raise UsageError("run: give at least one --mavlink CONN or --can IFACE:CHANNEL")
    if args.baud is not None and not any(map(_is_serial, args.mavlink)):
        _warn(f"--baud {args.baud} is ignored: it applies to serial --mavlink connections, and none is given")
    if args.request_rate_hz is not None and not args.mavlink:
        _warn(f"--request-rate {args.request_rate_hz:g} is ignored: it asks MAVLink vehicles, and no --mavlink is given")
    if args.bitrate is not None and all(spec.partition(":")[0] in CAN_WITHOUT_BITRATE for spec in args.can):
        _warn(f"--bitrate {args.bitrate} is ignored: {', '.join(CAN_WITHOUT_BITRATE)} buses take none")
    if args.overwrite and not args.record:
        _warn("--overwrite is ignored: it applies to --record, and none is given")


def _check_listen(args: argparse.Namespace) -> None:
    if args.zenoh_connect and args.zenoh_listen:
        _warn("--zenoh-connect overrides --zenoh-listen: the listener connects to the --zenoh-connect endpoints only")


def _check_signing_key(config: FuserConfig) -> None:
    """The signing key file, if one is named, can be read and holds a key: a missing or unusable key file is an input
    file the command cannot run without (exit 2), found before any link or log is opened."""
    try:
        config.link.signing_key()
    except SourceError as exc:
        raise UsageError(str(exc)) from exc


def _read_files(args: argparse.Namespace) -> list[tuple[str, str]]:
    """The files the command reads, each with what it is: its logs, ``--config``, ``--signing-key-file``."""
    logs = getattr(args, "log", None) or getattr(args, "source", None) or []
    named = [("the input log", log) for log in ([logs] if isinstance(logs, str) else logs)]
    named += [(f"the {option} file", getattr(args, attr, None)) for option, attr in
              (("--config", "config"), ("--signing-key-file", "signing_key_file"))]
    return [(what, path) for what, path in named if path]


def _check_output(path: str, option: str, reads: Iterable[tuple[str, str]] = ()) -> None:
    """A file can be written at ``path``: a regular file or nothing yet (not a folder, a device, a pipe, nor read-only),
    in a folder that exists and is writable, and none of the files the command reads (``reads``, :func:`_read_files`):
    a replay or an import would replace its own input (``replay hover.mcap -o hover.mcap`` left its output where the
    log had been; a .BIN or a .tlog goes the same way, by the same rename). Checked before the command starts, so it
    fails at once with one line (a recorder process would die on it)."""
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"cannot write {option} {path}: it is a folder; name a file (in it, or elsewhere)")
    if target.exists() and not target.is_file():  # replay -o /dev/null renamed its MCAP over the device (as root)
        raise UsageError(f"cannot write {option} {path}: it is not a regular file (a device, a pipe or a socket); name a file")
    for what, read in reads:
        if target.resolve() == Path(read).resolve() or (target.exists() and Path(read).exists() and os.path.samefile(target, read)):
            raise UsageError(f"cannot write {option} {path}: it is {what} {read}, which would be lost; name another file")
    if target.exists() and not os.access(target, os.W_OK):
        raise UsageError(f"cannot write {option} {path}: the file is not writable")
    folder = target.resolve().parent
    if not folder.is_dir():
        raise UsageError(f"cannot write {option} {path}: the folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise UsageError(f"cannot write {option} {path}: the folder {folder} is not writable")


def _check_not_a_recording(path: str, overwrite: bool) -> None:
    """``run --record`` onto an existing file: refused without ``--overwrite``. A live flight's recording cannot be
    made again (a replay's or an import's output can, from its input), and the recorder truncates the file as it
    opens it: the same command run twice, as one does flight after flight, would lose the first."""
    target = Path(path)
    if target.is_file() and not overwrite:
        size = target.stat().st_size
        raise UsageError(f"cannot write --record {path}: the file exists ({size:,} bytes, an earlier recording?); name "
                         "another file, or add --overwrite to replace it")


def _check_output_folder(path: str, option: str) -> None:
    """A folder can be written at ``path``, or created there (with its parents): neither it nor an ancestor is a file."""
    target = Path(path)
    existing = next((p for p in (target, *target.parents) if p.exists()), Path.cwd())
    if not existing.is_dir():
        where = "it is a file" if existing == target else f"{existing} is a file"
        raise UsageError(f"cannot write {option} {path}: {where}, not a folder")
    if not os.access(existing, os.W_OK):
        raise UsageError(f"cannot write {option} {path}: the folder {existing} is not writable")


# --------------------------------------------------------------------------- commands


DEFAULT_VEHICLE = {"sim": "sim", "run": "vehicle", "listen": "*"}
"""The vehicle name a command uses when none is configured: a live vehicle's estimates are not published as the
simulator's, and a listener hears every vehicle (``*`` in a zenoh key expression)."""


def _config(args: argparse.Namespace) -> FuserConfig:
    overrides: dict[str, Any] = {"vehicle": args.vehicle, "rate_hz": args.rate_hz}
    if args.no_mag:
        overrides["mag.enabled"] = False
    for name in ("listen", "connect"):
        if getattr(args, f"zenoh_{name}", None):
            overrides[f"zenoh.{name}"] = tuple(getattr(args, f"zenoh_{name}"))
    if getattr(args, "attitude_sigma_deg", None) is not None:
        overrides["attitude.mode"] = "always"
        overrides["attitude.sigma_deg"] = args.attitude_sigma_deg
    if getattr(args, "no_attitude", False):
        overrides["attitude.mode"] = "off"
    for name in ("system", "component", "signing_key_file", "dialect", "request_rate_hz"):
        overrides[f"link.{name}"] = getattr(args, name, None)
    if getattr(args, "any_sender", False):
        overrides["link.lock_first_autopilot"] = False
    config = load_config(args.config, overrides)
    command = getattr(args, "command", None)
    if command in DEFAULT_VEHICLE:
        from fuser.publish import check_vehicle

        if config.vehicle is None:
            config = config.replace(vehicle=DEFAULT_VEHICLE[command])
        check_vehicle(config.vehicle, listening=command == "listen")
    return config


def _load_config(args: argparse.Namespace) -> FuserConfig | None:
    """The configuration of a command that takes ``--config``, every error in it a one-line usage error."""
    if not hasattr(args, "config"):
        return None
    try:
        return _config(args)
    except OSError as e:
        raise UsageError(f"cannot read --config {args.config}: {e.strerror or e}") from e
    except (TypeError, ValueError) as e:
        raise UsageError(f"bad configuration: {e}") from e  # load_config's message names the file


def _beside_ros2_router(config: FuserConfig, args: argparse.Namespace) -> FuserConfig:
    """With ``--ros2`` through a router and the zenoh endpoints left at their defaults, the fuser's own zenoh
    session joins that router as well instead of listening on its port (7447 both): one router, no clash."""
    ros2 = config.ros2
    wants_ros2 = getattr(args, "ros2", False) or ros2.enabled
    defaults = FuserConfig().zenoh
    if not wants_ros2 or not ros2.connect_to_router or config.zenoh != defaults or getattr(args, "no_zenoh", False):
        return config
    log.info("zenoh: publishing through the ROS 2 router %s (not listening on its port)", ros2.router_endpoint)
    return dataclasses.replace(config, zenoh=dataclasses.replace(defaults, listen=(), connect=(ros2.router_endpoint,)))


def _publisher(stack: ExitStack, config: FuserConfig, args: argparse.Namespace):
    """The zenoh publisher, open, or a one-line error naming the endpoint and what to do instead."""
    if getattr(args, "no_zenoh", False):
        return None
    from fuser.publish import ZenohOpenError, ZenohPublisher, zenoh_config

    try:
        pub = ZenohPublisher.open(zenoh_config(list(config.zenoh.listen), list(config.zenoh.connect)), config.vehicle)
    except ZenohOpenError as e:
        if e.endpoint_in_use:
            raise FuserError(
                f"zenoh cannot listen on {e.endpoint_in_use}: the port is in use (another bingham-fuser, or a zenoh router "
                f"such as ROS 2's rmw_zenoh); listen elsewhere with --zenoh-listen tcp/127.0.0.1:PORT, or connect to that "
                f"router with --zenoh-connect {e.endpoint_in_use} (or --no-zenoh)") from e
        endpoints = ", ".join((*config.zenoh.listen, *config.zenoh.connect))
        hint = ": an endpoint is <protocol>/<address>, e.g. tcp/127.0.0.1:7447" if e.malformed else ""
        raise type(e)(f"zenoh cannot open a session with endpoints {endpoints}: {e.reason}{hint}", malformed=e.malformed) from e
    stack.callback(pub.close)
    return pub


_SOURCE_ERRORS: tuple[type[BaseException], ...] = (SourceError, OSError, ValueError, OverflowError)
"""What opening a source raises for a link that is not there: the drivers' own SourceError (naming what is wrong),
and what pymavlink, pyserial and sockets raise beneath them; python-can's CanError is added where it is caught."""


def _reason(exc: BaseException) -> str:
    text = re.sub(r"\[Errno -?\d+\] ", "", str(exc)) or type(exc).__name__
    return "connection refused (nothing listens there)" if isinstance(exc, ConnectionRefusedError) else text


def _open_source(stack: ExitStack, label: str, factory: Callable[[], Any]) -> Any:
    """Open a source in ``stack``; a failure is one line naming the source."""
    import can

    try:
        return stack.enter_context(factory())
    except can.CanInterfaceNotImplementedError as e:  # a known interface whose driver or package is missing here
        raise UsageError(f"cannot open {label}: {_reason(e)}") from e
    except (*_SOURCE_ERRORS, can.CanError) as e:
        raise FuserError(f"cannot open {label}: {_reason(e)}") from e
    except Exception as e:  # noqa: BLE001 - third-party driver code (python-can plugins) may raise anything when its library is absent
        raise FuserError(f"cannot open {label}: {type(e).__name__}: {e}") from e


def _cmd_sim(args: argparse.Namespace, config: FuserConfig) -> int:
    from drivers.scenarios import flight as make_flight
    from drivers.scenarios import require as require_scenario
    from fuser.pipeline import Pipeline
    from fuser.record import McapRecorder, RecorderProcess
    from fuser.simulate import run_sim
    from fuser.wallclock import WallClock

    _check_sim(args)
    try:
        require_scenario(args.scenario)
    except ImportError as exc:  # an optional dependency of the scenario (jsbsim for fixedwing)
        raise UsageError(f"sim: {exc}") from exc
    try:
        flight = make_flight(args.scenario, args.seed, args.imu_rate, args.duration)
    except ValueError as exc:  # one the simulator cannot lay out (drivers.sim.SimConfig): before any output opens
        raise UsageError(f"sim: {exc}") from exc
    if args.send or args.send_can:
        from fuser.sender import run_sender

        if args.truth:
            _check_output(args.truth, "--truth", _read_files(args))
        return run_sender(args, flight, _stop_on_signal())
    if args.record:
        _check_output(args.record, "--record", _read_files(args))
    clock = WallClock.start(args.speed) if args.speed > 0 else None
    with ExitStack() as stack:
        config = _beside_ros2_router(config, args)
        pub = _publisher(stack, config, args)
        extra = _extra_outputs(stack, config, args)  # before the recorder: an output that cannot open leaves no file
        rec = None
        if args.record:
            # paced runs record in a separate process, like live ones; a full-speed run
            # would outpace it, so it records in-process and loses nothing
            recorder = McapRecorder if clock is None else RecorderProcess
            timeline = clock.metadata() if clock is not None else {"time": "the simulated flight's clock (--speed 0)"}
            rec = recorder(args.record, metadata={"source": "bingham-fuser sim", "scenario": args.scenario, "seed": str(args.seed), **timeline})
            stack.callback(rec.close)
        pipeline = Pipeline(config, ([rec.write_sample] if rec else []) + extra.inputs, _estimate_sinks(pub, rec) + extra.estimates)
        stop = _stop_on_signal()
        _warm_up(config)  # paced, before the clock matters (fuser/warmup.py); at full speed, so the first run says it compiles
        seconds = (flight.t_ns[-1] - flight.t_ns[0]) / 1e9
        print(f"sim: {args.scenario} flight, {seconds:.0f} s at {'full speed' if args.speed <= 0 else f'{args.speed:g}x'}"
              + (f", publishing on bingham_fuser/{config.vehicle}/attitude and .../status" if pub else "")
              + (f", recording {args.record}" if rec else ""), file=sys.stderr)
        run = run_sim(pipeline, flight, args.transport, args.speed, ([rec.write_truth] if rec else []) + extra.truth, stop, clock=clock,
                      status_sinks=_status_sinks(pub, rec, extra), health=_health(pub, rec, extra))
    print(f"sim: {run.samples} samples -> {run.estimates} estimates in {run.wall_s:.1f} s")
    if isinstance(rec, RecorderProcess):
        _check_recorder(rec, args.record)
    if args.record:
        _print_scores(args.record)
    return 0


def _check_recorder(rec: Any, path: str) -> None:
    """A recorder process that died during the run has lost what came after (estimates, inputs, status): the command
    failed (exit 1), whatever else it did. Called once the recorder is closed (``close`` then says how it ended)."""
    if not rec.close():
        if rec.write_failed:
            raise FuserError(f"cannot write {path}: its disk refused a write (full, or an I/O error; the recorder's line above "
                             "says which); it holds what was written before, up to its last complete chunk")
        raise FuserError(f"the recorder process died during the run: {path} holds only what it had written (up to its "
                         f"last complete chunk); {rec.dropped} writes after it were dropped")


def _warm_up(config: FuserConfig) -> None:
    """Compile (or load) the filter's kernels before a live run (fuser/warmup.py)."""
    from fuser.warmup import warm_up

    log.debug("kernels ready in %.1f s", warm_up(config, _say_compiling))


def _say_compiling() -> None:
    """Tell the user why the command waits (a cold numba cache, :mod:`fuser.compiling`)."""
    from fuser.compiling import COMPILING

    print(COMPILING, file=sys.stderr, flush=True)


def _estimate_sinks(pub: Any, rec: Any) -> list:
    """Where each estimate goes: zenoh first, so a subscriber never waits for the recorder's
    serialisation (measured: +0.1 ms on the publish latency the other way round), then MCAP."""
    return [s for s in (pub.publish_estimate if pub else None, rec.write_estimate if rec else None) if s]


def _status_sinks(pub: Any, rec: Any, extra: Any) -> list:
    """Where the status goes once a second: the recording's ``/status``, zenoh's ``.../status``, the other outputs."""
    return [s for s in (rec.write_status if rec else None, (lambda t, d: pub.publish_status(d)) if pub else None) if s] + extra.status


def _health(pub: Any, rec: Any, extra: Any) -> Callable[[], dict]:
    """The outputs' entries in the status: the recorder's, the publisher's, the other outputs'."""
    def health() -> dict:
        out: dict[str, Any] = {}
        if rec is not None:
            out["recorder"] = rec.health()
        if pub is not None:
            out["publisher"] = {"errors": pub.errors, "subscribed": pub.has_subscribers}
        return out | extra.health_status()

    return health


def _extra_outputs(stack: ExitStack, config: FuserConfig, args: argparse.Namespace):
    """--ros2, --foxglove, --mavlink-out (fuser/outputs.py); a missing package is a usage error naming its extra."""
    from fuser.outputs import open_outputs

    try:
        return open_outputs(stack, config, args)
    except ImportError as exc:
        raise UsageError(str(exc)) from exc


def _cmd_run(args: argparse.Namespace, config: FuserConfig) -> int:
    _check_run(args)
    _check_signing_key(config)
    if args.record:
        _check_output(args.record, "--record", _read_files(args))
        _check_not_a_recording(args.record, args.overwrite)
    from drivers.sources import DroneCanSource, MavlinkSource
    from fuser.inputs import silence_hint, source_report
    from fuser.live import LiveRunner
    from fuser.pipeline import Pipeline
    from fuser.record import RecorderProcess
    from fuser.wallclock import WallClock

    with ExitStack() as stack:
        sources: dict[str, Any] = {}
        for conn in args.mavlink:
            options = {"baud": args.baud or DEFAULT_BAUD} if _is_serial(conn) else {}
            sources[f"mavlink:{conn}"] = _open_source(stack, f"MAVLink {conn}", partial(MavlinkSource, conn, config.link, **options))
        for spec in args.can:
            interface, _, channel = spec.partition(":")
            extra = {} if interface in CAN_WITHOUT_BITRATE else {"bitrate": args.bitrate or DEFAULT_BITRATE}
            sources[f"can:{spec}"] = _open_source(stack, f"CAN bus {spec}",
                                                  partial(DroneCanSource, interface=interface, channel=channel, **extra))
        config = _beside_ros2_router(config, args)
        pub = _publisher(stack, config, args)
        extra = _extra_outputs(stack, config, args)  # before the recorder: an output that cannot open leaves no file
        clock = WallClock.start()
        rec = None
        if args.record:
            rec = RecorderProcess(args.record, metadata={"source": "bingham-fuser run", **clock.metadata()})
            stack.callback(rec.close)
        pipeline = Pipeline(config, ([rec.write_sample] if rec else []) + extra.inputs, _estimate_sinks(pub, rec) + extra.estimates)
        _warm_up(config)  # after everything has opened: an input or output that cannot is reported at once
        runner = LiveRunner(pipeline, sources, _status_sinks(pub, rec, extra), _health(pub, rec, extra), clock)
        _stop_on_signal(runner.stop)
        status = runner.run(args.duration, lambda: print(f"run: fusing {', '.join(sources)} at {config.rate_hz:g} Hz; Ctrl-C to stop",
                                                         file=sys.stderr, flush=True))
    print(f"run: {status['estimates']} estimates; loop {status['loop']}; latency {status['latency']}")
    _print_inputs(source_report(name, src) for name, src in sources.items())
    for name, src in sources.items():
        if not src.stats.get("accepted"):  # the whole run without a sample from it: say what it did receive
            _warn(silence_hint(name, src.stats, src.transport))
    if rec is not None:
        _check_recorder(rec, args.record)
    return 0


def _cmd_replay(args: argparse.Namespace, config: FuserConfig) -> int:
    from fuser.replay import replay

    _check_signing_key(config)
    if batch.is_batch(args):
        if args.out_dir is not None:
            _check_output_folder(args.out_dir, "--out-dir")
        return batch.command(args, config, notice=_say_compiling)
    log = args.log[0]
    _check_output(args.output, "--output", _read_files(args))
    summary = replay(log, args.output, config, notice=_say_compiling)
    if summary.imported is not None:
        _print_not_imported(log, summary.imported)
    if summary.skipped:
        _warn(f"{log} is damaged: skipped {summary.skipped.describe()}; replayed the rest")
    elif summary.incomplete:
        _warn(f"{log} is incomplete ({summary.incomplete}): replayed its complete chunks")
    if summary.not_recorded:
        _warn(f"{sum(summary.not_recorded.values())} records could not be stored in {args.output} and were left out "
              f"({', '.join(f'{k}={v}' for k, v in sorted(summary.not_recorded.items()))})")
    compiled = f"; {summary.compile_seconds:.1f} s of it compiling the filter" if summary.compile_seconds >= batch.COMPILE_SHOWN_S else ""
    print(f"replay: {summary.samples} samples -> {summary.estimates} estimates in {summary.seconds:.2f} s "
          f"({summary.samples_per_s:,.0f} samples/s{compiled}); {args.output}")
    if summary.counters:
        print("counters: " + ", ".join(f"{k}={v}" for k, v in sorted(summary.counters.items())))
    _print_inputs([summary.inputs] if summary.inputs else [])
    _print_scores(args.output)
    return 0


def _print_not_imported(source: str, skipped: dict[str, int]) -> None:
    """What an import left out of ``source``, and a warning if the log was cut short."""
    if skipped:
        print(f"not imported: {skipped}")
    if skipped.get("incomplete_tail_bytes"):
        _warn(f"{source} ends with {skipped['incomplete_tail_bytes']:,} bytes that are not a whole record: cut short "
              "(power lost while logging, a download that stopped?) or garbage after the last record; imported what is there")


def _cmd_import(args: argparse.Namespace, config: None) -> int:  # noqa: ARG001
    from fuser.importers import read_sensor_log, write_mcap

    check_log_file(args.source, "import")
    _check_output(args.output, "--output", _read_files(args))
    cfg_out = str(Path(args.output).with_suffix(".toml")) if args.config_out is None else (args.config_out or None)
    if cfg_out is not None:
        _check_output(cfg_out, "--config-out" if args.config_out else "the settings file (--output with .toml, or --config-out)",
                      [*_read_files(args), ("the --output file", args.output)])
    try:
        data = read_sensor_log(args.source, args.format, args.start, args.duration, progress=sys.stderr)
    except UsageError as exc:
        raise type(exc)(f"import: {exc}") from exc
    s = write_mcap(data, args.output, cfg_out, progress=sys.stderr)
    print(f"import: {s.imu} IMU + {s.attitude} attitude + {s.gnss} GNSS messages through MAVLink, {s.truth} reference attitudes -> {s.path}")
    _print_not_imported(args.source, s.skipped)
    print(f"reference field (N, E, D gauss): {s.mag_field_ned_gauss}" + (f"; replay with --config {s.config_path}" if s.config_path else ""))
    if s.refused:
        print(f"decoder refused: {s.refused}")
    return 0


def _cmd_listen(args: argparse.Namespace, config: FuserConfig) -> int:
    from fuser.publish import key, listen, zenoh_config

    _check_listen(args)
    # a listener connects to the fuser's endpoint unless told otherwise
    connect = list(config.zenoh.connect) or list(config.zenoh.listen)
    print(f"listen: estimates on {key(config.vehicle, 'attitude')} through {', '.join(connect)}; Ctrl-C to stop",
          file=sys.stderr, flush=True)
    listen(zenoh_config(listen=[], connect=connect), config.vehicle, json_output=args.json, count=args.count)
    return 0


def _cmd_report(args: argparse.Namespace, config: None) -> int:  # noqa: ARG001
    require_package("matplotlib", "report", "report")
    check_log_file(args.log, "report")
    _check_output_folder(args.output, "--output")
    from fuser.report import write_report

    for line in write_report(args.log, Path(args.output)):
        print(line)
    return 0


def _print_inputs(reports) -> None:
    """What each input gave, by reason, and a warning on stderr where little of it reached the loop."""
    for report in reports:
        print("\n".join(report.lines()))
        if (warning := report.warning()) is not None:
            print(warning, file=sys.stderr)


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


# --------------------------------------------------------------------------- errors


def _explain(exc: BaseException) -> tuple[int, str]:
    """Exit code and the one line for an exception that ended a command."""
    if isinstance(exc, FuserError):
        return exc.exit_code, str(exc)
    if isinstance(exc, (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError)):
        return EXIT_USAGE, f"{exc.strerror or exc}: {exc.filename}" if exc.filename else str(exc)
    if isinstance(exc, OSError):
        return EXIT_RUNTIME, f"{exc.strerror or exc}" + (f": {exc.filename}" if exc.filename else "")
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        return EXIT_USAGE, f"a package this needs is not installed: {exc.name} (pip install {exc.name.split('.')[0]})"
    return EXIT_RUNTIME, (f"internal error: {type(exc).__name__}: {exc} "
                          "(run again with --verbose for the traceback, and please report it)")


def _not_taken(argv: list[str], extra: list[str]) -> str:
    """What to name of the arguments argparse left over: each unknown option with its value where the value came
    right after it (``--rate 5``). Not a token argparse took elsewhere: in ``report --rate 5 LOG`` the 5 became
    the log and ``LOG`` is left over, and only ``--rate`` is the mistake."""
    options = [k for k, token in enumerate(extra) if token.startswith("-")]
    if not options:
        return " ".join(extra)
    named, at = [], -1
    for k in options:
        named.append(extra[k])
        if extra[k] not in argv[at + 1:]:  # not as given (argparse's own rewriting): the option alone
            continue
        at = argv.index(extra[k], at + 1)  # the same option given twice: each where it stands
        value = extra[k + 1] if k + 1 < len(extra) else None
        if value is not None and not value.startswith("-") and at + 1 < len(argv) and argv[at + 1] == value:
            named.append(value)
    return " ".join(named)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns the exit code (0 done, 1 failed while running, 2 bad usage)."""
    verbose = 0
    try:
        args, extra = _parser().parse_known_args(argv)
        if extra:
            raise UsageError(f"{args.command} does not take {_not_taken(list(sys.argv[1:] if argv is None else argv), extra)} "
                             f"(see {PROG} {args.command} --help)")
        verbose = args.verbose
        logging.basicConfig(level=[logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)],
                            format="%(levelname)s %(name)s: %(message)s")
        config = _load_config(args)
        return args.handler(args, config)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError as exc:
        if not stdout_gone():  # a socket's (a TCP link), not the reader of what the command prints
            return _failed(exc, verbose)
        return 0  # its reader stopped (replay ... | head -1): the command had done its work, printing is what ended
    except Exception as exc:  # noqa: BLE001 - the one place every failure becomes one line and an exit code
        return _failed(exc, verbose)


def _failed(exc: BaseException, verbose: int) -> int:
    """The one line on stderr (and, with ``-v``, the traceback) of a failure; its exit code."""
    code, line = _explain(exc)
    if verbose:
        traceback.print_exc()
    print(f"{PROG}: {line}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
