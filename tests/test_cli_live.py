"""Live runs as a user starts them: a spoofed packet cannot kill the recorder, and every channel is on Unix time.

* ``bingham-fuser run -o rec.mcap`` fed HIGHRES_IMU built with pymavlink
  directly; in the middle, one packet from a new system id with
  ``time_usec`` = 2^63 (a time the MCAP cannot store as uint64 ns). The
  recorder stays alive, the file is complete and holds every packet of the
  vehicle, exactly, and the spoofed one is accounted for.
* a paced ``bingham-fuser sim`` records and publishes on one timeline: every
  record of every channel, and every zenoh payload, lies within the wall-clock
  span of the run; the recorded monotonic -> Unix offset maps them back into
  the monotonic span; replay keeps those times and stays byte-identical.

The recordings are read with mcap's own reader, not the project's.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from fuser.config import FuserConfig
from fuser.publish import subscribe, zenoh_config
from fuser.replay import replay

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from local_net import free_port  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
FUSER = [sys.executable, "-m", "fuser.cli"]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
IMU_HZ = 100
SEND_S = 2.0
SPOOF_AT_S = 1.0


def read_mcap(path: Path) -> tuple[dict[str, list[tuple[int, int, dict]]], dict[str, dict[str, str]]]:
    """topic -> [(log_time, publish_time, payload)], and the metadata, with mcap's reader (CRCs checked, footer required)."""
    out: dict[str, list[tuple[int, int, dict]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for _, channel, m in reader.iter_messages(log_time_order=True):
            out.setdefault(channel.topic, []).append((m.log_time, m.publish_time, json.loads(m.data)))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return out, metadata


def wait_for_line(proc: subprocess.Popen, text: str, timeout: float = 60.0) -> list[str]:
    """stderr lines up to and including the first containing ``text``."""
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise AssertionError(f"process ended before {text!r}: {''.join(lines)}")
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"no {text!r} within {timeout} s")


def test_spoofed_time_packet_cannot_kill_the_recorder(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_DGRAM)
    rec = tmp_path / "rec.mcap"
    t_start = time.time_ns()
    proc = subprocess.Popen(FUSER + ["run", "--mavlink", f"udpin:127.0.0.1:{port}", "--no-zenoh", "-o", str(rec),
                                     "--duration", str(SEND_S + 1.6)],
                            cwd=tmp_path, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_line(proc, "run: fusing")  # the link is open
        vehicle = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="common")
        spoofer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=77, source_component=1, dialect="common")
        sent_us: list[int] = []
        t0_us, start = 5_000_000, time.monotonic()
        for k in range(int(SEND_S * IMU_HZ)):
            time.sleep(max(0.0, start + k / IMU_HZ - time.monotonic()))
            if k % IMU_HZ == 0:  # an autopilot's heartbeat once a second: the fuser locks onto this vehicle
                vehicle.mav.heartbeat_send(2, 3, 0, 0, 4)  # MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA, active
                spoofer.mav.heartbeat_send(2, 3, 0, 0, 4)
            t_us = t0_us + k * 1_000_000 // IMU_HZ
            vehicle.mav.highres_imu_send(t_us, 0.0, 0.0, -9.81, 0.01, 0.0, 0.0, 0.21, 0.0, 0.43, 1013.0, 0.0, 0.0, 20.0, 0x1FF)
            sent_us.append(t_us)
            if k == int(SPOOF_AT_S * IMU_HZ):
                spoofer.mav.highres_imu_send(2**63, 0.0, 0.0, -9.81, 0.01, 0.0, 0.0, 0.21, 0.0, 0.43, 1013.0, 0.0, 0.0, 20.0, 0x1FF)
        vehicle.close()
        spoofer.close()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    t_end = time.time_ns()
    assert proc.returncode == 0, err
    assert "Traceback" not in err

    records, metadata = read_mcap(rec)  # complete: mcap's reader needs the footer the child writes on a clean close
    imu = records["/input/imu"]
    assert [d["t_ns"] for _, _, d in imu] == [t * 1000 for t in sent_us]  # every packet of the vehicle, exactly
    assert all(d["source"]["system"] == 1 for _, _, d in imu)
    status = records["/status"][-1][2]
    assert status["recorder"]["alive"] is True
    accepted = next(v for k, v in status["sources"].items() if k.startswith("mavlink:"))["accepted"]
    # the spoofed packet was stopped either by the decoder's range check or by the recorder's own guard
    assert accepted - len(sent_us) == status["recorder"]["rejected"] in (0, 1)
    assert len(records["/estimate"]) > 0.9 * IMU_HZ * SEND_S
    # every channel on the run's Unix timeline, the mapping recorded
    assert metadata["bingham_fuser"]["time"] == "unix"
    for topic, msgs in records.items():
        assert t_start <= msgs[0][0] and msgs[-1][0] <= t_end, topic


PACED_S = 6.0
"""Seconds of the paced (real-time) simulated flight."""


@pytest.fixture(scope="module")
def paced_sim(tmp_path_factory: pytest.TempPathFactory) -> dict:
    folder = tmp_path_factory.mktemp("paced")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    received: list = []
    statuses: list = []
    t0, m0 = time.time_ns(), time.monotonic_ns()
    proc = subprocess.Popen(FUSER + ["sim", "--duration", str(PACED_S), "-o", "sim.mcap", "--vehicle", "wallclock",
                                     "--zenoh-listen", endpoint],
                            cwd=folder, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with subscribe(zenoh_config(listen=[], connect=[endpoint]), "wallclock", received.append,  # dials until the fuser listens
                       on_status=statuses.append):
            out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    t1, m1 = time.time_ns(), time.monotonic_ns()
    assert proc.returncode == 0, err
    records, metadata = read_mcap(folder / "sim.mcap")
    return {"path": folder / "sim.mcap", "records": records, "metadata": metadata, "received": received, "statuses": statuses,
            "unix": (t0, t1), "monotonic": (m0, m1), "stdout": out}


def test_paced_sim_records_every_channel_on_the_runs_unix_timeline(paced_sim: dict) -> None:
    t0, t1 = paced_sim["unix"]
    m0, m1 = paced_sim["monotonic"]
    records = paced_sim["records"]
    assert {"/input/imu", "/input/attitude", "/estimate", "/pose", "/truth/pose"} <= set(records)
    offset = int(paced_sim["metadata"]["bingham_fuser"]["unix_minus_monotonic_ns"])
    for topic, msgs in records.items():
        times = [t for t, _, _ in msgs]
        assert t0 <= times[0] and times[-1] <= t1, topic  # (today: estimates at host uptime, truth at flight time)
        assert m0 <= times[0] - offset and times[-1] - offset <= m1, topic  # the recorded mapping is the run's
    for topic in ("/pose", "/truth/pose"):  # Foxglove's time stamps are on the same timeline
        assert all(d["timestamp"]["sec"] * 10**9 + d["timestamp"]["nsec"] == t for t, _, d in records[topic])
    # the truth keeps the vehicle's clock as its publish time, so it still scores against sensor_t_ns
    publish_s = [p / 1e9 for _, p, _ in records["/truth/pose"]]
    assert PACED_S - 1.0 < max(publish_s) - min(publish_s) < PACED_S + 1.0 and max(publish_s) < 60  # the flight on its own clock
    assert "error against simulator truth" in paced_sim["stdout"]


def test_paced_sim_gives_the_status_once_a_second_as_a_live_run_does(paced_sim: dict) -> None:
    """On zenoh (``.../status``) and in the recording (``/status``), with the loop's counters, the updates'
    diagnostics and the outputs' health; the counts grow from one status to the next."""
    recorded = [d for _, _, d in paced_sim["records"]["/status"]]
    assert PACED_S - 2 <= len(recorded) <= PACED_S
    for status in recorded:
        assert {"estimates", "loop", "model", "diagnostics", "recorder", "publisher"} <= set(status)
        assert status["recorder"]["alive"] is True and status["recorder"]["dropped"] == 0
    estimates = [s["estimates"] for s in recorded]
    assert estimates == sorted(estimates) and 0 < estimates[0] < estimates[-1] <= len(paced_sim["records"]["/estimate"])
    assert set(recorded[-1]["diagnostics"]) >= {"gravity", "heading"}  # the latest of each update
    assert paced_sim["statuses"] and all(set(s) == set(recorded[0]) for s in paced_sim["statuses"])


def test_paced_sim_publishes_unix_times_on_zenoh(paced_sim: dict) -> None:
    t0, t1 = paced_sim["unix"]
    received = paced_sim["received"]
    assert len(received) > 100
    assert all(t0 <= e.t_ns <= t1 for e in received)
    recorded = {d["t_ns"] for _, _, d in paced_sim["records"]["/estimate"]}
    assert {e.t_ns for e in received} <= recorded


def test_replay_of_a_live_recording_keeps_its_times_and_bytes(paced_sim: dict, tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    replay(paced_sim["path"], a, FuserConfig(), progress=None)
    replay(paced_sim["path"], b, FuserConfig(), progress=None)
    assert a.read_bytes() == b.read_bytes()
    again, _ = read_mcap(a)
    assert [t for t, _, _ in again["/input/imu"]] == [t for t, _, _ in paced_sim["records"]["/input/imu"]]
    t0, t1 = paced_sim["unix"]
    assert all(t0 <= t <= t1 for t, _, _ in again["/estimate"])


def test_a_faster_paced_sim_still_ticks_at_the_loop_rate_in_flight_time() -> None:
    """At --speed 4 the run's clock runs 4x: one estimate per 1/rate_hz of *flight* time (on the vehicle's
    clock, ``sensor_t_ns``), not of wall time (which would be one per 40 ms of flight)."""
    from drivers.scenarios import flight as make_flight
    from fuser.pipeline import Pipeline
    from fuser.simulate import run_sim

    flight = make_flight("full", seed=1, imu_rate_hz=200.0, duration_s=4.0)
    config = FuserConfig()
    estimates: list = []
    run_sim(Pipeline(config, outputs=[estimates.append]), flight, speed=4.0)
    estimates = [e for e in estimates if not e.predicted]  # the ticks' (between them, the output predictor's)
    steps_ns = np.diff([e.sensor_t_ns for e in estimates])
    assert len(estimates) > 100
    assert np.median(steps_ns) == round(1e9 / config.rate_hz)


def test_a_paced_sim_sends_its_first_sample_on_time(monkeypatch: pytest.MonkeyPatch) -> None:
    """The simulator lays out the whole flight's samples when asked for the first (50-150 ms): that is not flight
    time. It was: every paced ``sim`` received its first sample 66 ms (146 ms on a fresh install) late against the
    rest of the flight's pacing, the next ones in a burst. Here the setup is made to take 300 ms of wall time, 1.2 s
    of the 4x clock."""
    import fuser.simulate as simulate
    from drivers.scenarios import flight as make_flight
    from fuser.pipeline import Pipeline
    from fuser.warmup import warm_up

    real = simulate.sim_ticks

    def slow_to_start(flight, transport="mavlink"):
        time.sleep(0.3)
        yield from real(flight, transport)

    warm_up(FuserConfig())  # the kernels loaded, as `sim` does before its clock: the first tick is not slow either
    monkeypatch.setattr(simulate, "sim_ticks", slow_to_start)
    flight = make_flight("full", seed=1, imu_rate_hz=200.0, duration_s=2.0)
    received: list[tuple[int, int]] = []
    simulate.run_sim(Pipeline(FuserConfig(), inputs=[lambda s, r: received.append((s.t_ns, r))]), flight, speed=4.0)
    sent, at = (np.array(v, dtype=np.int64) for v in zip(*received))
    lag_ms = ((at - at[0]) - (sent - sent[0])) / 1e6  # the run's clock runs at 4x: flight time
    assert len(received) > 300
    assert abs(np.median(lag_ms)) < 50, np.median(lag_ms)  # the first sample on the flight's pacing (it was 1200 ms late here)
