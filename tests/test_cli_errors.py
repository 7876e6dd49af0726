"""Every bad input a user can give ends in one line on stderr, exit 2 (usage) or 1 (runtime), no traceback,
and no output file left behind.

Each case runs ``bingham-fuser`` in a subprocess of its own, in an empty
folder (with only the files the case needs); all of them start at once, so
the whole table costs about one interpreter start per core.
"""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from fuser.compiling import COMPILING
from local_net import free_port

ROOT = Path(__file__).resolve().parent.parent
LOG = ROOT / "logs" / "sim_hover.mcap"


@dataclass
class Case:
    argv: list[str]
    code: int
    says: tuple[str, ...]
    """Substrings of the one stderr line."""
    files: dict[str, bytes] = field(default_factory=dict)
    python: str | None = None
    """Run ``python -c`` this instead of the command (to hide a package)."""
    writes: tuple[str, ...] = ()
    """Files the command is expected to write (a run that succeeds despite damage)."""


def _text(s: str) -> bytes:
    return s.encode()


def damaged_log() -> tuple[bytes, int, int]:
    """logs/sim_hover.mcap with the compressed data of its 4th chunk corrupted; the chunk's size and message count."""
    from test_fuser_damaged import chunks_of, damage

    spans, contents = chunks_of(LOG)
    return damage(LOG.read_bytes(), *spans[3], "data"), spans[3][1], len(contents[3])


def mcap_without_messages() -> bytes:
    """A sound MCAP file the recorder opened and closed without a record."""
    import io

    from mcap.writer import Writer

    out = io.BytesIO()
    writer = Writer(out)
    writer.start(profile="", library="test")
    writer.finish()
    return out.getvalue()


DAMAGED, DAMAGED_BYTES, DAMAGED_MESSAGES = damaged_log()
BUSY_PORT = free_port()
CLOSED_PORT = free_port()
RANDOM = bytes((i * 7919 + 13) % 251 for i in range(5000))
BAD_FUSER = "[fuser]\n"

CASES: dict[str, Case] = {
    # damaged logs (issue 12, item 5)
    "replay-missing-input": Case(["replay", "nope.mcap", "-o", "out.mcap"], 2, ("nope.mcap",)),
    "replay-empty-file": Case(["replay", "in.mcap", "-o", "out.mcap"], 2, ("in.mcap", "empty"), {"in.mcap": b""}),
    "replay-random-bytes": Case(["replay", "in.mcap", "-o", "out.mcap"], 2, ("not an MCAP",), {"in.mcap": RANDOM}),
    "replay-text-named-mcap": Case(["replay", "in.mcap", "-o", "out.mcap"], 2, ("not an MCAP",), {"in.mcap": _text("hello\n" * 50)}),
    "replay-text-named-tlog": Case(["replay", "in.tlog", "-o", "out.mcap"], 2, ("in.tlog is not a MAVLink telemetry log",), {"in.tlog": _text("hello\n" * 50)}),
    "replay-no-messages": Case(["replay", "in.mcap", "-o", "out.mcap"], 1, ("nothing to replay in in.mcap", "it holds no messages"),
                               {"in.mcap": mcap_without_messages()}),  # it said "no record could be read (None)"
    "replay-damaged-chunk": Case(["replay", "in.mcap", "-o", "out.mcap"], 0,
                                 ("warning: in.mcap is damaged", f"skipped 1 chunk ({DAMAGED_BYTES:,} bytes, {DAMAGED_MESSAGES} messages)"),
                                 {"in.mcap": DAMAGED}, writes=("out.mcap",)),
    "report-of-an-imported-log": Case(["report", str(ROOT / "logs" / "px4_sample_cut.mcap"), "-o", "rep"], 2,
                                      ("holds no estimates", "bingham-fuser replay")),
    "report-of-a-text-file": Case(["report", "in.mcap", "-o", "rep"], 2, ("not an MCAP",), {"in.mcap": _text("hello\n")}),
    # connection strings and buses (issue 12, item 6)
    "mavlink-notaport": Case(["run", "--mavlink", "notaport", "--no-zenoh"], 2, ("notaport", "udpin:HOST:PORT")),
    "mavlink-bad-ip": Case(["run", "--mavlink", "999.1.1.1", "--no-zenoh"], 2, ("999.1.1.1", "not a MAVLink connection")),
    "mavlink-refused": Case(["run", "--mavlink", f"tcp:127.0.0.1:{CLOSED_PORT}", "--no-zenoh", "-o", "rec.mcap"], 1,
                            (f"tcp:127.0.0.1:{CLOSED_PORT}", "refused")),
    "can-unknown-interface": Case(["run", "--can", "nope:can0", "--no-zenoh"], 2, ("unknown CAN interface 'nope'", "socketcan")),
    "can-unknown-channel": Case(["run", "--can", "slcan:/dev/no-such-adapter", "--no-zenoh"], 1, ("cannot open CAN bus", "/dev/no-such-adapter")),
    # an output that is one of the command's own inputs: refused before anything is read or written
    "replay-onto-its-log": Case(["replay", "in.mcap", "-o", "./in.mcap"], 2, ("cannot write --output ./in.mcap", "input log in.mcap"),
                                {"in.mcap": LOG.read_bytes()}),
    "replay-onto-its-dataflash-log": Case(["replay", "flight.BIN", "-o", "flight.BIN"], 2, ("input log flight.BIN", "would be lost"),
                                          {"flight.BIN": RANDOM}),
    "replay-onto-its-config": Case(["replay", str(LOG), "-o", "c.toml", "--config", "c.toml"], 2, ("--config file c.toml",),
                                   {"c.toml": _text("[fuser]\nrate_hz = 100.0\n")}),
    "import-onto-its-log": Case(["import", "flight.bin", "-o", "flight.bin"], 2, ("input log flight.bin",), {"flight.bin": RANDOM}),
    "import-settings-onto-its-output": Case(["import", "flight.bin", "-o", "flight.toml"], 2,
                                            ("settings file", "flight.toml: it is the --output file"), {"flight.bin": RANDOM}),
    "record-onto-its-config": Case(["run", "--mavlink", f"udpin:127.0.0.1:{CLOSED_PORT}", "--no-zenoh", "--duration", "1", "--record", "c.toml",
                                    "--config", "c.toml"], 2, ("--config file c.toml",), {"c.toml": _text("[fuser]\nrate_hz = 100.0\n")}),
    # a live flight's recording is not replaced by the next run's unless asked (a replay's output can be made again)
    "record-onto-an-earlier-recording": Case(["run", "--mavlink", f"udpin:127.0.0.1:{CLOSED_PORT}", "--no-zenoh", "--duration", "1",
                                              "--record", "flight.mcap"], 2,
                                             ("cannot write --record flight.mcap: the file exists", "add --overwrite"),
                                             {"flight.mcap": LOG.read_bytes()}),
    # configuration
    "config-wrong-type": Case(["replay", str(LOG), "-o", "out.mcap", "--config", "c.toml"], 2, ("fuser.rate_hz", "fast"),
                              {"c.toml": _text(BAD_FUSER + 'rate_hz = "fast"\n')}),
    "config-zero-time-constant": Case(["replay", str(LOG), "-o", "out.mcap", "--config", "c.toml"], 2,
                                      ("fuser.accel.lowpass_s must be >= 0.001 s, got 0",), {"c.toml": _text("[fuser.accel]\nlowpass_s = 0\n")}),
    "config-old-flat-key": Case(["replay", str(LOG), "-o", "out.mcap", "--config", "c.toml"], 2,
                                ("fuser.accel_lowpass_s has moved", "[fuser.accel]"), {"c.toml": _text(BAD_FUSER + "accel_lowpass_s = 0\n")}),
    # a port in use, e.g. by a ROS 2 rmw_zenoh router on 7447 (here a plain TCP listener on a free port)
    "zenoh-port-in-use": Case(["sim", "--scenario", "hover", "--speed", "0", "-o", "sim.mcap", "--zenoh-listen", f"tcp/127.0.0.1:{BUSY_PORT}"],
                              1, (f"tcp/127.0.0.1:{BUSY_PORT}", "in use", "--zenoh-listen", f"--zenoh-connect tcp/127.0.0.1:{BUSY_PORT}")),
    # options where they do not act (issue 16, item 5)
    "report-rate-no-mag": Case(["report", str(LOG), "--rate", "5", "--no-mag"], 2, ("report does not take --rate 5 --no-mag",)),
    # a missing optional package
    "report-without-matplotlib": Case(["report", str(LOG), "-o", "rep"], 2, ("matplotlib", "pip install"),
                                      python="import sys; sys.modules['matplotlib'] = None; from fuser.cli import main; sys.exit(main(sys.argv[1:]))"),
}


@dataclass
class Result:
    code: int
    stderr: str
    stdout: str
    left: set[str]
    changed: set[str]
    """The case's own files whose bytes the command changed."""


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Result]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    busy = socket.socket()
    busy.bind(("127.0.0.1", BUSY_PORT))
    busy.listen()
    procs: dict[str, tuple[subprocess.Popen, Path]] = {}
    try:
        for name, case in CASES.items():
            folder = tmp_path_factory.mktemp(name)
            for fname, data in case.files.items():
                (folder / fname).write_bytes(data)
            head = [sys.executable, "-c", case.python] if case.python else [sys.executable, "-m", "fuser.cli"]
            procs[name] = (subprocess.Popen(head + case.argv, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                            stdin=subprocess.DEVNULL, text=True), folder)
        out = {}
        for name, (proc, folder) in procs.items():
            stdout, stderr = proc.communicate(timeout=120)
            changed = {f for f, data in CASES[name].files.items() if (folder / f).is_file() and (folder / f).read_bytes() != data}
            out[name] = Result(proc.returncode, stderr, stdout, {p.name for p in folder.iterdir()}, changed)
        return out
    finally:
        for proc, _ in procs.values():
            if proc.poll() is None:
                proc.kill()
        busy.close()


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_one_line_and_an_exit_code(name: str, results: dict[str, Result]) -> None:
    case = CASES[name]
    r = results[name]
    lines = [x for x in r.stderr.splitlines() if x != COMPILING]  # a cold numba cache: a replay says it compiles first
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert lines[0].startswith("bingham-fuser: ")
    for text in case.says:
        assert text in lines[0], lines[0]
    assert r.code == case.code, lines[0]
    assert r.left == set(case.files) | set(case.writes), f"stray output: {r.left - set(case.files)}"
    assert not r.changed, f"changed: {r.changed}"


def test_verbose_shows_the_traceback_then_the_line(tmp_path: Path) -> None:
    (tmp_path / "in.mcap").write_bytes(b"hello\n")
    r = subprocess.run([sys.executable, "-m", "fuser.cli", "replay", "in.mcap", "-o", "out.mcap", "-v"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 2
    assert r.stderr.startswith("Traceback") and "NotAnMcapError" in r.stderr
    assert r.stderr.splitlines()[-1].startswith("bingham-fuser: in.mcap is not an MCAP")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mcap"]


def test_an_unexpected_failure_is_one_line_too(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """A bug is reported as an internal error in one line (exit 1), with a pointer to --verbose."""
    from fuser import cli

    def broken(args, config):  # noqa: ARG001
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(cli, "_cmd_replay", broken)
    assert cli.main(["replay", str(LOG), "-o", "x.mcap"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == ["bingham-fuser: internal error: ZeroDivisionError: division by zero "
                   "(run again with --verbose for the traceback, and please report it)"]


IN_PROCESS: dict[str, tuple[list[str], int, tuple[str, ...]]] = {
    "mavlink-bad-port": (["run", "--mavlink", "udpin:0.0.0.0:99999", "--no-zenoh"], 2, ("99999", "0-65535")),
    "can-no-channel": (["run", "--can", "virtual:", "--no-zenoh"], 2, ("INTERFACE:CHANNEL",)),
    # --mavlink-out is checked like --mavlink, before anything runs (it was opened, failed, logged and the run went on)
    "mavlink-out-bad-port": (["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "", "--mavlink-out", "udpout:127.0.0.1:99999"],
                             2, ("argument --mavlink-out", "99999", "0-65535")),
    "mavlink-out-notaconn": (["run", "--mavlink", "udpin:127.0.0.1:9", "--no-zenoh", "--duration", "1", "--mavlink-out", "notaconn"], 2,
                             ("argument --mavlink-out", "'notaconn' is not a MAVLink connection")),
    "mavlink-out-bad-config": (["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "", "--config", "mavout.toml"], 2,
                               ("bad configuration", "mavlink_out.connection", "'notaconn' is not a MAVLink connection")),
    "mavlink-out-no-device": (["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "sim.mcap", "--mavlink-out", "/dev/no-such-tty"],
                              1, ("cannot open --mavlink-out /dev/no-such-tty",)),
    "run-without-inputs": (["run", "--no-zenoh"], 2, ("--mavlink",)),
    "run-record-into-missing-folder": (["run", "--mavlink", "udpin:127.0.0.1:9", "-o", "no/rec.mcap"], 2, ("no/rec.mcap", "does not exist")),
    "replay-into-missing-folder": (["replay", str(LOG), "-o", "no/out.mcap"], 2, ("no/out.mcap", "does not exist")),
    # an output that names a folder (or a folder output that names a file): refused before anything runs
    "run-record-into-a-folder": (["run", "--mavlink", "udpin:127.0.0.1:9", "--no-zenoh", "--duration", "1", "-o", "adir"], 2,
                                 ("cannot write --record adir: it is a folder",)),
    "sim-record-into-a-folder": (["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "adir"], 2,
                                 ("cannot write --record adir: it is a folder",)),
    "sim-truth-into-a-folder": (["sim", "--scenario", "hover", "--send", "udpout:127.0.0.1:9", "--truth", "adir"], 2,
                                ("cannot write --truth adir: it is a folder",)),
    "replay-into-a-folder": (["replay", str(LOG), "-o", "adir"], 2, ("cannot write --output adir: it is a folder",)),
    "replay-out-dir-a-file": (["replay", str(LOG), str(LOG), "--out-dir", "afile"], 2, ("cannot write --out-dir afile: it is a file",)),
    "import-into-a-folder": (["import", "text.ulg", "-o", "adir"], 2, ("cannot write --output adir: it is a folder",)),
    "import-config-out-a-folder": (["import", "text.ulg", "-o", "x.mcap", "--config-out", "adir"], 2,
                                   ("cannot write --config-out adir: it is a folder",)),
    "report-into-a-file": (["report", str(LOG), "-o", "afile"], 2, ("cannot write --output afile: it is a file",)),
    "report-under-a-file": (["report", str(LOG), "-o", "afile/rep"], 2, ("cannot write --output afile/rep: afile is a file",)),
    "config-missing": (["replay", str(LOG), "-o", "out.mcap", "--config", "none.toml"], 2, ("none.toml",)),
    "run-signing-key-missing": (["run", "--mavlink", "udpin:127.0.0.1:9", "--no-zenoh", "--signing-key-file", "no.key"], 2,
                                ("link.signing_key_file: cannot read no.key", "No such file")),
    "replay-signing-key-missing": (["replay", str(LOG), "-o", "out.mcap", "--signing-key-file", "no.key"], 2,
                                   ("link.signing_key_file: cannot read no.key",)),
    "replay-signing-key-empty": (["replay", str(LOG), "-o", "out.mcap", "--signing-key-file", "empty.key"], 2, ("empty.key", "is empty")),
    "config-syntax": (["replay", str(LOG), "-o", "out.mcap", "--config", "syntax.toml"], 2, ("syntax.toml", "line 2")),
    "config-unknown-key": (["replay", str(LOG), "-o", "out.mcap", "--config", "unknown.toml"], 2,
                           ("bad configuration: unknown.toml: fuser.mag_sigma is not a setting",)),
    "import-config": (["import", "x.ulg", "-o", "x.mcap", "--config", "c.toml"], 2, ("import does not take --config",)),
    "import-missing-file": (["import", "x.ulg", "-o", "x.mcap"], 2, ("import: no such log file: x.ulg",)),
    "import-a-folder": (["import", "adir", "-o", "x.mcap"], 2, ("import: a folder, not a log file: adir",)),
    "replay-a-folder": (["replay", "adir", "-o", "x.mcap"], 2, ("a folder, not a log file: adir",)),
    "report-a-folder": (["report", "adir", "-o", "rep"], 2, ("report: a folder, not a log file: adir",)),
    "replay-a-device": (["replay", "/dev/zero", "-o", "x.mcap"], 2, ("not a regular file (a device, a pipe or a socket)", "/dev/zero")),
    "report-missing-log": (["report", "x.mcap", "-o", "rep"], 2, ("report: no such log file: x.mcap",)),
    "listen-no-zenoh": (["listen", "--no-zenoh"], 2, ("listen does not take --no-zenoh",)),
    "listen-rate": (["listen", "--rate", "5"], 2, ("listen does not take --rate 5",)),
    "report-rate-before-log": (["report", "--rate", "5", str(LOG)], 2, ("report does not take --rate (see",)),  # 5 was taken as the log
    "option-twice": (["listen", "--foo", "1", "--foo", "2"], 2, ("listen does not take --foo 1 --foo 2 (see",)),
    "config-endless": (["replay", str(LOG), "-o", "out.mcap", "--config", "/dev/zero"], 2,
                       ("bad configuration: /dev/zero: more than 1024 KiB: not a settings file",)),  # read until memory ran out
    "config-not-a-table": (["replay", str(LOG), "-o", "out.mcap", "--config", "scalar.toml"], 2,
                           ("bad configuration: scalar.toml: fuser must be a table of settings ([fuser]), got 3",)),
    "replay-vehicle": (["replay", str(LOG), "-o", "out.mcap", "--vehicle", "x"], 2, ("replay does not take --vehicle x",)),
    "sim-send-with-record": (["sim", "--send", "udpout:127.0.0.1:9", "-o", "sim.mcap"], 2, ("--record acts on a fuser running here",)),
    "sim-send-with-fusion": (["sim", "--send", "udpout:127.0.0.1:9", "--rate", "50", "--no-mag"], 2, ("--rate, --no-mag act",)),
    "sim-send-speed": (["sim", "--send", "udpout:127.0.0.1:9", "--speed", "4"], 2, ("--speed must be 1",)),
    "sim-truth-without-send": (["sim", "--truth", "t.npz", "--garbage", "5"], 2, ("--truth, --garbage act only with --send",)),
    "sim-bad-outage": (["sim", "--send", "udpout:127.0.0.1:9", "--outage", "soon"], 2, ("--outage", "AT:SECONDS")),
    # numbers beyond what the simulator can do: an internal error (MemoryError, OverflowError, numpy's seed), or run as given
    "sim-imu-rate-too-fast": (["sim", "--speed", "0", "--no-zenoh", "--imu-rate", "1e9"], 2, ("argument --imu-rate", "from 1 to 10000 Hz")),
    "sim-imu-rate-too-slow": (["sim", "--speed", "0", "--no-zenoh", "--imu-rate", "0.001"], 2, ("argument --imu-rate",)),
    "sim-speed-overflow": (["sim", "--no-zenoh", "--speed", "1e300"], 2, ("argument --speed", "from 0 to 1000 times real time")),
    "sim-speed-nan": (["sim", "--no-zenoh", "--speed", "nan"], 2, ("argument --speed",)),
    "sim-negative-seed": (["sim", "--speed", "0", "--no-zenoh", "--seed", "-1"], 2, ("argument --seed", "a whole number of at least 0")),
    "sim-flight-too-long": (["sim", "--speed", "0", "--no-zenoh", "--duration", "1e12"], 2,
                            ("sim: SimConfig: 1e+12 s at 400 Hz is a flight of 4e+14 IMU samples", "2,000,000 at most")),
    "sim-flight-too-short": (["sim", "--speed", "0", "--no-zenoh", "--duration", "0.001"], 2, ("0.4 IMU samples", "needs 2 at least")),
    "sim-outage-nan": (["sim", "--send", "udpout:127.0.0.1:9", "--outage", "nan:1"], 2, ("argument --outage",)),
    "sim-start-at-inf": (["sim", "--send", "udpout:127.0.0.1:9", "--start-at", "+inf"], 2, ("argument --start-at",)),
    "sim-garbage-flood": (["sim", "--send", "udpout:127.0.0.1:9", "--garbage", "1e12"], 2, ("argument --garbage", "from 0 to 1e+06")),
    "foxglove-bad-port": (["sim", "--speed", "0", "--no-zenoh", "-o", "sim.mcap", "--foxglove", "99999"], 2,
                          ("argument --foxglove", "from 0 to 65535")),  # it logged an error and ran without the view
    "listen-count-zero": (["listen", "--count", "0"], 2, ("argument --count", "of at least 1")),  # it listened for ever
    "run-negative-bitrate": (["run", "--can", "virtual:x", "--no-zenoh", "--bitrate", "-1"], 2, ("argument --bitrate",)),
    "run-zero-baud": (["run", "--mavlink", "/dev/ttyS0", "--no-zenoh", "--baud", "0"], 2, ("argument --baud",)),
    # a vehicle name that is no zenoh key chunk: every put failed (one error logged) and the run published nothing, exit 0
    "sim-vehicle-empty": (["sim", "--speed", "0", "-o", "", "--vehicle", ""], 2, ("fuser.vehicle '' is not a name", "it is empty")),
    "run-vehicle-with-slash": (["run", "--mavlink", "udpin:127.0.0.1:9", "--vehicle", "fleet/7"], 2, ("fuser.vehicle 'fleet/7'", "'/'")),
    "sim-vehicle-wildcard": (["sim", "--speed", "0", "-o", "", "--vehicle", "*"], 2, ("fuser.vehicle '*'",)),
    "sim-vehicle-question-mark": (["sim", "--speed", "0", "-o", "", "--vehicle", "x?y"], 2, ("fuser.vehicle 'x?y'", "forbidden")),
    "listen-vehicle-with-slash": (["listen", "--vehicle", "a/b"], 2, ("fuser.vehicle 'a/b'",)),
    "import-text-named-ulg": (["import", "text.ulg", "-o", "x.mcap"], 2, ("cannot read text.ulg as a px4 log",)),
    "abbreviation": (["sim", "--dur", "5"], 2, ("sim does not take --dur 5",)),
    "unknown-command": (["fly"], 2, ("invalid choice: 'fly'",)),
}


@pytest.mark.parametrize("name", list(IN_PROCESS))
def test_options_only_where_they_act(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    """The same one-line contract for the cases that fail while parsing (in-process: no interpreter start each)."""
    from fuser.cli import main

    argv, code, says = IN_PROCESS[name]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "syntax.toml").write_text("[fuser]\nrate_hz = \n")
    (tmp_path / "unknown.toml").write_text("[fuser]\nmag_sigma = 0.1\n")
    (tmp_path / "scalar.toml").write_text("fuser = 3\n")
    (tmp_path / "text.ulg").write_text("hello\n")
    (tmp_path / "empty.key").write_bytes(b"")
    (tmp_path / "adir").mkdir()
    (tmp_path / "mavout.toml").write_text('[fuser.mavlink_out]\nconnection = "notaconn"\n')
    (tmp_path / "afile").write_bytes(b"")
    if name == "import-text-named-ulg":
        pytest.importorskip("pyulog")
    before = {p.name for p in tmp_path.iterdir()}
    assert main(argv) == code
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("bingham-fuser: "), err
    for text in says:
        assert text in err[0], err[0]
    if "--config" in argv:  # named once: "bad configuration in x.toml: x.toml: ..." said it twice
        assert err[0].count(argv[argv.index("--config") + 1]) == 1, err[0]
    assert {p.name for p in tmp_path.iterdir()} == before


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes are POSIX")
@pytest.mark.parametrize("argv", [["replay", str(LOG), "-o", "out"], ["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "out"],
                                  ["import", "x.ulg", "-o", "out"]], ids=["replay", "sim", "import"])
def test_an_output_that_is_a_pipe_or_a_device_is_refused_and_left_as_it_was(argv, tmp_path, monkeypatch, capsys) -> None:
    """``replay LOG -o /dev/null`` renamed its finished MCAP over the device (as root, /dev/null became a file); a named
    pipe shows it without harm: it was replaced by a regular file."""
    from fuser.cli import main

    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "out")
    (tmp_path / "x.ulg").write_bytes(b"")
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == f"bingham-fuser: cannot write {'--record' if argv[0] == 'sim' else '--output'} out: " \
                                              "it is not a regular file (a device, a pipe or a socket); name a file"
    assert stat.S_ISFIFO(os.stat(tmp_path / "out").st_mode)


def test_a_reader_that_stops_reading_ends_the_printing_not_the_command(tmp_path) -> None:
    """``replay LOG -o out.mcap | head -1`` wrote its output and then said "bingham-fuser: Broken pipe", exit 1 (what a
    pipeline under ``set -o pipefail`` takes for a failure); here the reader has gone before anything is printed."""
    proc = subprocess.Popen([sys.executable, "-m", "fuser.cli", "replay", str(LOG), "-o", str(tmp_path / "out.mcap")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    proc.stdout.close()
    assert proc.wait(120) == 0
    err = proc.stderr.read()
    assert "Broken pipe" not in err and "Traceback" not in err and "Exception ignored" not in err, err
    from fuser.record import read_log

    assert read_log(tmp_path / "out.mcap").complete


def test_version(capsys: pytest.CaptureFixture) -> None:
    from importlib.metadata import version

    from fuser.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"bingham-fuser {version('bingham-fuser')}"


def test_a_mavlink_out_port_in_use_is_one_line_before_anything_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                     capsys: pytest.CaptureFixture) -> None:
    """A port another program holds: exit 1 (a link that cannot be opened, as for --mavlink), no recording left."""
    from fuser.cli import main

    monkeypatch.chdir(tmp_path)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        conn = f"udpin:127.0.0.1:{busy.getsockname()[1]}"
        code = main(["run", "--mavlink", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--no-zenoh", "--duration", "1",
                     "--mavlink-out", conn, "-o", "rec.mcap"])
    err = capsys.readouterr().err.splitlines()
    assert code == 1 and len(err) == 1, err
    assert err[0].startswith(f"bingham-fuser: cannot open --mavlink-out {conn}: ") and "in use" in err[0], err
    assert list(tmp_path.iterdir()) == []


DURATION_COMMANDS = {"run": ["run", "--mavlink", "udpin:127.0.0.1:9"], "sim": ["sim"], "import": ["import", "x.ulg", "-o", "x.mcap"]}


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-5", "0", "soon"])
@pytest.mark.parametrize("command", list(DURATION_COMMANDS))
def test_a_duration_is_a_finite_positive_number_of_seconds(command: str, value: str, capsys: pytest.CaptureFixture) -> None:
    """nan and inf ran forever, 0 and negative durations stopped at once with exit 0: all are refused while parsing."""
    from fuser.cli import main

    assert main([*DURATION_COMMANDS[command], f"--duration={value}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("bingham-fuser: argument --duration: ") and "a finite number of seconds > 0" in err[0], err


@pytest.mark.parametrize("value", ["nan", "inf", "-5"])
def test_an_import_start_is_a_finite_number_of_seconds_from_zero(value: str, capsys: pytest.CaptureFixture) -> None:
    """nan and inf failed deep in the reader (ValueError, OverflowError), -5 was taken as 0."""
    from fuser.cli import main

    assert main([*DURATION_COMMANDS["import"], f"--start={value}"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("bingham-fuser: argument --start: ") and "a finite number of seconds >= 0" in err[0], err


@pytest.mark.parametrize(("argv", "warning"), [
    (["sim", "--scenario", "hover", "--duration", "30"], "--scenario hover is a flight of fixed length: it overrides --duration 30"),
    (["run", "--mavlink", "udpin:0.0.0.0:14550", "--baud", "115200"], "--baud 115200 is ignored"),
    (["run", "--can", "virtual:x", "--bitrate", "500000"], "--bitrate 500000 is ignored"),
    (["run", "--can", "virtual:x", "--request-rate", "50"], "--request-rate 50 is ignored: it asks MAVLink vehicles"),
    (["run", "--can", "virtual:x", "--overwrite"], "--overwrite is ignored: it applies to --record"),
    (["listen", "--zenoh-connect", "tcp/127.0.0.1:7447", "--zenoh-listen", "tcp/127.0.0.1:7448"], "--zenoh-connect overrides --zenoh-listen"),
])
def test_an_option_overridden_by_another_is_warned_about(argv: list[str], warning: str, capsys: pytest.CaptureFixture) -> None:
    from fuser import cli

    args = cli._parser().parse_args(argv)
    {"sim": cli._check_sim, "run": cli._check_run, "listen": cli._check_listen}[argv[0]](args)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("bingham-fuser: warning: ") and warning in err[0], err


@pytest.mark.parametrize("link", ["symbolic", "hard"])
def test_an_output_that_is_the_input_under_another_name_is_refused(link: str, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``replay flight.mcap -o other.mcap`` where other.mcap is a link to flight.mcap: the same file, refused."""
    from fuser.cli import main

    log, other = tmp_path / "flight.mcap", tmp_path / "other.mcap"
    log.write_bytes(LOG.read_bytes())
    other.symlink_to(log) if link == "symbolic" else os.link(log, other)
    assert main(["replay", str(log), "-o", str(other)]) == 2
    assert f"it is the input log {log}" in capsys.readouterr().err
    assert log.read_bytes() == LOG.read_bytes()


def test_overwrite_lets_run_replace_an_earlier_recording(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from fuser.cli import main
    from fuser.record import read_log

    flight = tmp_path / "flight.mcap"
    flight.write_bytes(LOG.read_bytes())
    argv = ["run", "--mavlink", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--no-zenoh", "--duration", "0.5",
            "--record", str(flight)]
    assert main(argv) == 2 and flight.read_bytes() == LOG.read_bytes()
    assert main([*argv, "--overwrite"]) == 0
    assert read_log(flight).metadata["bingham_fuser"]["source"] == "bingham-fuser run"  # this run's, no longer the sim's
