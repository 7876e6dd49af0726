"""Replaying the logs in logs/: determinism, accuracy against their truth, golden estimates.

The simulated logs hold the estimates the simulator run wrote through the
same pipeline (``bingham-fuser sim --speed 0``). Their accuracy is checked
against the simulator's truth (independent of the filter); once that holds,
those recorded estimates are the golden file a replay must reproduce.
"""

import json
import struct
from bisect import bisect_left
from pathlib import Path

import numpy as np
import pytest

from drivers.scenarios import scenario
from drivers.sim import mavlink_stream
from fuser.cli import main
from fuser.config import FuserConfig, load_config
from fuser.evaluate import attitude_errors
from fuser.record import read_log
from fuser.replay import replay
from fuser.report import errors_of_log

from log_order import order_violations

LOGS = Path(__file__).resolve().parent.parent / "logs"
SIM_LOGS = sorted(LOGS.glob("sim_*.mcap"))

# RMS error bounds after the first 5 s (degrees), above the worst of seeds 0, 3, 7 (README, "Accuracy";
# the multirotor with rotor drag and GNSS velocity aiding, 200 Hz IMU, the published state carried ahead of its tick):
# hover 1.53-2.04, aggressive 1.45-3.07, magnet 1.89-2.53, dropout 2.42-3.35. Aggressive was 6.22-7.06 before GNSS
# aiding (bound 8.0).
BOUNDS = {"hover": 2.6, "aggressive": 4.0, "magnet": 3.3, "dropout": 4.5}
# Reported uncertainty against actual error, seed 0, with GNSS aiding: within 2x with the magnet (1.64), through the
# dropouts (1.51) and in the hover (1.73); the aggressive flight 2.45x (see _pessimistic: the heading floor
# fitted on BROAD's distorted fields is pessimistic for the simulator's exact one).


def config_for(log: Path) -> FuserConfig:
    toml = log.with_suffix(".toml")
    return load_config(toml if toml.exists() else None)


def test_every_scenario_has_a_log():
    assert {p.stem.removeprefix("sim_") for p in SIM_LOGS} == set(BOUNDS)


@pytest.mark.parametrize("log", SIM_LOGS, ids=lambda p: p.stem)
def test_recorded_estimates_are_accurate_against_truth(log):
    name, err = errors_of_log(log)
    assert name == "truth"
    rms = err.rms(5.0)
    assert rms["total"] < BOUNDS[log.stem.removeprefix("sim_")], rms


def _pessimistic(log: Path):
    """Not met with GNSS aiding (seed 0): aggressive reports 3.56 deg for 1.37 deg (2.6x), the heading floor of the
    model error (2.5 deg, fitted on BROAD's distorted indoor fields) and the magnetometer's 2-deg correlated error
    dominating an exact simulated field. Hover met since that floor was refitted (3.52 for 2.05, 1.72x; it was 4.09
    for 2.04 with the 3.25-deg floor)."""
    marks = [pytest.mark.xfail(strict=True, reason=_pessimistic.__doc__)] if log.stem == "sim_aggressive" else []
    return pytest.param(log, id=log.stem, marks=marks)


@pytest.mark.parametrize("log", [_pessimistic(p) for p in SIM_LOGS])
def test_reported_uncertainty_is_honest(log):
    """The reported RMS deviation is within a factor 2 of the actual RMS error."""
    rms = errors_of_log(log)[1].rms(5.0)
    assert 0.5 < rms["uncertainty"] / rms["total"] < 2.0, rms


@pytest.mark.parametrize("log", SIM_LOGS + sorted(LOGS.glob("broad_*.mcap")) + sorted(LOGS.glob("px4_*.mcap")), ids=lambda p: p.stem)
def test_replay_twice_is_byte_identical(log, tmp_path):
    config = config_for(log)
    replay(log, tmp_path / "a.mcap", config, progress=None)
    replay(log, tmp_path / "b.mcap", config, progress=None)
    assert (tmp_path / "a.mcap").read_bytes() == (tmp_path / "b.mcap").read_bytes()


ALL_LOGS = SIM_LOGS + sorted(LOGS.glob("broad_*.mcap")) + sorted(LOGS.glob("px4_*.mcap"))


@pytest.fixture(scope="module", params=ALL_LOGS, ids=lambda p: p.stem)
def replayed(request, tmp_path_factory) -> tuple[Path, Path]:
    """Each log of logs/ and its replay (with the log's configuration)."""
    log = request.param
    out = tmp_path_factory.mktemp(log.stem) / "out.mcap"
    replay(log, out, config_for(log), progress=None)
    return log, out


def test_replay_writes_every_record_in_log_time_order(replayed):
    """The log's /truth/pose goes in among the estimates and inputs of its time, not after them all (it did: 1,876
    records out of order on the PX4 cut, 1,200 on the hover flight); no channel goes back either."""
    log, out = replayed
    assert order_violations(out) == {}
    assert len(read_log(out).truth()) == len(read_log(log).truth()) > 100


def test_replay_records_the_status_once_a_second(replayed):
    """/status was empty in every replay though the README lists it. A replay writes it as sim does, once a second
    of the log's receive time: of a sim --speed 0 recording, the very records the simulator wrote."""
    log, out = replayed
    status = read_log(out).of(["/status"])
    if log in SIM_LOGS:
        assert [m[1:] for m in status] == [m[1:] for m in read_log(log).of(["/status"])]
    received = [r for _, r in read_log(log).inputs()]
    seconds = range(1, (received[-1] - received[0]) // 10**9 + 1)  # the first sample received at or after each second
    assert [m.log_time for m in status] == [received[bisect_left(received, received[0] + k * 10**9)] for k in seconds]
    assert len(status) > 10
    last = json.loads(status[-1].data)
    assert set(last) == {"estimates", "loop", "model", "diagnostics", "recorder"} and last["loop"]["ticks"] > 100


def test_sim_records_the_truth_after_the_ticks_due_before_it(tmp_path, capsys):
    """The truth received with an IMU tick (log time: its receive time) went in before the loop's ticks due by that
    time, then those ticks' estimates 1 ms behind it: 1,595 records out of order in the hover flight (399 on /tf).
    The committed flights, written by the same command, are in order too."""
    out = tmp_path / "sim.mcap"
    assert main(["sim", "--scenario", "hover", "--speed", "0", "--imu-rate", "200", "--no-zenoh", "-o", str(out)]) == 0
    assert order_violations(out) == {}
    assert len(read_log(out).truth()) > 1000
    assert {log.stem: order_violations(log) for log in SIM_LOGS} == {log.stem: {} for log in SIM_LOGS}


def test_replayed_estimates_are_stamped_strictly_forward(replayed):
    """fuser/IO.md: the stamps only go forward. Two estimates shared one stamp: a tick due the instant a sample
    arrived, then that sample's prediction (342 times on the BROAD cut), and a tick the wait made due in the past,
    after a prediction (once on the PX4 cut). The tick-only channels too."""
    contents = read_log(replayed[1])
    for topic in ("/estimate", "/pose", "/tf", "/diagnostics"):
        times = [m.log_time for m in contents.of([topic])]
        assert len(times) > 100 and all(a < b for a, b in zip(times, times[1:])), topic
    stamps = [e.t_ns for e in contents.estimates()]
    assert all(a < b for a, b in zip(stamps, stamps[1:]))


@pytest.mark.parametrize("log", SIM_LOGS, ids=lambda p: p.stem)
def test_replay_reproduces_the_golden_estimates(log, tmp_path):
    replay(log, tmp_path / "out.mcap", config_for(log), progress=None)
    golden = read_log(log).estimates()
    again = read_log(tmp_path / "out.mcap").estimates()
    assert len(again) == len(golden) > 100
    np.testing.assert_allclose([e.q_wxyz for e in again], [e.q_wxyz for e in golden], atol=1e-9)
    np.testing.assert_allclose([e.uncertainty_deg for e in again], [e.uncertainty_deg for e in golden], rtol=1e-9)
    assert [e.t_ns for e in again] == [e.t_ns for e in golden]


def test_truncated_log_replays_what_survived(tmp_path):
    """A log cut short (recorder killed) replays its complete chunks without error."""
    src = SIM_LOGS[0]
    cut = tmp_path / "cut.mcap"
    data = src.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    summary = replay(cut, tmp_path / "out.mcap", FuserConfig(), progress=None)
    full = len(read_log(src).inputs())
    assert 0 < summary.samples < full
    assert summary.estimates > 0


def test_tlog_replay_matches_truth(tmp_path):
    """A MAVLink .tlog (8-byte big-endian microsecond receive time, then the packet) replays
    through the same loop; the estimate is scored against the simulator's truth."""
    flight = scenario("hover", seed=3)
    tlog = tmp_path / "flight.tlog"
    with open(tlog, "wb") as f:
        for t_ns, _, data in mavlink_stream(flight):
            while data:  # one record per MAVLink 2 packet: 10 header bytes, payload, 2 CRC bytes
                size = 12 + data[1]
                f.write(struct.pack(">Q", (t_ns + 1_000_000) // 1000) + data[:size])
                data = data[size:]
    replay(tlog, tmp_path / "out.mcap", FuserConfig(), progress=None)
    est = read_log(tmp_path / "out.mcap").estimates()
    err = attitude_errors(
        np.array([e.sensor_t_ns for e in est]), np.array([e.q_wxyz for e in est]),
        np.array([e.uncertainty_deg for e in est]), flight.t_ns, flight.q_true,
    )
    assert err.rms(5.0)["total"] < BOUNDS["hover"]


def test_cli_replay_and_report(tmp_path, capsys):
    out = tmp_path / "out.mcap"
    assert main(["replay", str(SIM_LOGS[0]), "-o", str(out)]) == 0
    assert main(["report", str(out), "-o", str(tmp_path / "report")]) == 0
    text = capsys.readouterr().out
    assert "error against simulator truth" in text
    png = tmp_path / "report" / "error.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("command", ["sim", "run", "replay", "listen", "report"])
def test_help_of_every_command(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert "usage: bingham-fuser" in capsys.readouterr().out


def test_config_file_with_unknown_key_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[fuser]\nrate_hz = 50\nmag_sigma = 0.1\n")
    assert main(["replay", str(SIM_LOGS[0]), "-o", str(tmp_path / "o.mcap"), "--config", str(bad)]) == 2
    assert "mag_sigma" in capsys.readouterr().err


def test_run_without_inputs_says_what_is_missing(capsys):
    assert main(["run", "--no-zenoh"]) == 2
    assert "--mavlink" in capsys.readouterr().err
