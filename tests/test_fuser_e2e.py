"""End to end, as a user runs it: a simulated vehicle on real links, `bingham-fuser run`, a zenoh subscriber elsewhere.

The vehicle sends MAVLink over UDP on 127.0.0.1 from another process
(`bingham-fuser sim --send`) and, as a second IMU on the same airframe,
DroneCAN frames on an in-process python-can virtual bus (no SocketCAN on these
machines); `bingham-fuser run` fuses both in-process and publishes on zenoh;
`bingham-fuser listen --json` in a third process receives the estimates, which
are scored against the simulator's truth (written by the sender, on its clock).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import numpy as np

from drivers.scenarios import scenario
from fuser import cli
from fuser.evaluate import attitude_errors
from fuser.publish import subscribe, zenoh_config
from fuser.sender import send_flight
from local_net import free_port, wait_for

ROOT = Path(__file__).resolve().parent.parent
FUSER = [sys.executable, "-m", "fuser.cli"]
LEAD_S = 3.0
"""From the sender being ready to its first sample: time to start the fuser and the subscriber."""
IMU_HZ = 200.0

# Bounds, measured on this machine (see the report in the test output): RMS of the
# total attitude error (degrees) of what the subscriber received.
HOVER_RMS_BOUND_DEG = 2.0
"""Hover, 2-6 s into the flight: the issue's aim; measured 1.8 live."""
AGGRESSIVE_RMS_BOUND_DEG = 12.0
"""The whole aggressive scenario from 2 s (hover, banked turns, fast manoeuvres): measured 10.0 live with two IMUs,
10.6-11.0 offline with one. The issue aims under 5: not met. The model's accelerometer low-pass (VQF-style, which
took the real BROAD trials from 46 to 3.1 deg) cannot remove the drag-free simulated multirotor's sustained
centripetal acceleration in long banked turns (README, "Accuracy")."""
MANOEUVRE_RMS_BOUND_DEG = 15.0
"""Only the fast manoeuvres (up to 500 deg/s, the last 7 s): measured 12.4 live."""


def sleep_until(unix_time: float) -> None:
    time.sleep(max(0.0, unix_time - time.time()))


class Proc:
    """A child process whose stdout lines are collected (with arrival times) by a thread; killed on close."""

    def __init__(self, argv: list[str]) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.popen = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[tuple[float, str]] = []
        self.err: list[str] = []
        self._threads = [threading.Thread(target=self._read, args=(self.popen.stdout, True), daemon=True),
                         threading.Thread(target=self._read, args=(self.popen.stderr, False), daemon=True)]
        for t in self._threads:
            t.start()

    def _read(self, stream, is_out: bool) -> None:
        for line in stream:
            if is_out:
                self.lines.append((time.time(), line.rstrip("\n")))
            else:
                self.err.append(line)

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
        self.popen.wait(10)
        for t in self._threads:
            t.join(5)

    def wait(self, timeout: float) -> int:
        code = self.popen.wait(timeout)
        for t in self._threads:
            t.join(5)
        return code

    def json_lines(self) -> list[dict]:
        return [json.loads(line) for _, line in self.lines if line.startswith("{")]


class FuserThread(threading.Thread):
    """`bingham-fuser run ...` in-process (it stops by itself with --duration)."""

    def __init__(self, argv: list[str]) -> None:
        super().__init__(name="fuser-run", daemon=True)
        self.argv = argv
        self.code: int | None = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.code = cli.main(self.argv)
        except BaseException as e:  # noqa: BLE001 - reported by the test
            self.error = e

    def finish(self, timeout: float, code: int = 0) -> None:
        """Wait for the run to stop by itself with exit status ``code``."""
        self.join(timeout)
        assert not self.is_alive(), "bingham-fuser run did not stop by itself"
        assert self.error is None, repr(self.error)
        assert self.code == code


class StatusTap:
    """An in-process zenoh subscriber on the status (and attitude) keys: what the fuser says about itself."""

    def __init__(self, endpoint: str, vehicle: str) -> None:
        self.status: list[tuple[float, dict]] = []
        self.estimates: list = []
        self._sub = subscribe(zenoh_config(listen=[], connect=[endpoint]), vehicle, self.estimates.append,
                              lambda d: self.status.append((time.time(), d)))

    def close(self) -> None:
        self._sub.close()


def errors_of(estimates: list[dict], truth: np.lib.npyio.NpzFile):
    """Errors of received estimate payloads against the truth, at their sensor times (the sender's clock)."""
    est = sorted(estimates, key=lambda d: d["t_ns"])
    t = np.array([d["sensor_t_ns"] for d in est], dtype=np.int64)
    q = np.array([d["q_wxyz"] for d in est])
    unc = np.array([d["uncertainty_deg"] for d in est])
    return attitude_errors(t, q, unc, truth["t_ns"], truth["q_wxyz"])


def window_rms(err, t0_ns: int, start_s: float, end_s: float) -> float:
    rel = (err.t_ns - t0_ns) / 1e9
    keep = (rel >= start_s) & (rel < end_s)
    assert keep.sum() > 0.9 * 100 * (end_s - start_s), f"too few estimates in {start_s}-{end_s} s: {keep.sum()}"
    return float(np.sqrt(np.mean(err.total_deg[keep] ** 2)))


def stop_all(procs: tuple[Proc | None, ...], tap: StatusTap | None, fuser: FuserThread | None) -> None:
    """Kill the helper processes, close the status tap and wait for the fuser thread: a test's cleanup."""
    for p in procs:
        if p is not None:
            p.kill()
    if tap is not None:
        tap.close()
    if fuser is not None:
        fuser.join(15)


def sender_start(sender: Proc, timeout: float = 30.0) -> float:
    """The Unix time the sender announced for its first sample (it prints it once the flight is built)."""
    def announced() -> bool:
        assert sender.popen.poll() is None or any("first sample at" in e for e in sender.err), "".join(sender.err)
        return any("first sample at" in e for e in sender.err)

    wait_for(announced, timeout, "the sender to start")
    return float(next(e for e in sender.err if "first sample at" in e).rsplit(" ", 1)[1])


def wait_listening(port: int, timeout: float = 10.0) -> None:
    def accepts() -> bool:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return True
        except OSError:
            return False

    wait_for(accepts, timeout, f"the fuser to listen on {port}")


def test_mavlink_udp_and_dronecan_virtual_bus_fused_and_received_over_zenoh(tmp_path: Path) -> None:
    vehicle = "e2e"
    udp, zport = free_port(socket.SOCK_DGRAM), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    channel = f"e2e-{os.getpid()}"
    truth_file = tmp_path / "truth.npz"
    can_flight = scenario("aggressive", seed=1, imu_rate_hz=IMU_HZ)  # a second IMU: same airframe, own noise
    flight_s = (can_flight.t_ns[-1] - can_flight.t_ns[0]) / 1e9
    # A 25-ms wait for samples in flight instead of the default 5: on a shared 2-core machine the
    # source thread is sometimes descheduled for >5 ms, and at 500 deg/s every gyro sample that
    # arrives after its tick has run (dropped as 'late') costs degrees that only gravity and the
    # magnetometer can win back (measured: 7 deg RMS in the manoeuvres with 5 ms on a quiet machine, 18 on a busy one).
    config = tmp_path / "fuser.toml"
    config.write_text("latency_ms = 25.0\n")
    sender = Proc(FUSER + ["sim", "--scenario", "aggressive", "--seed", "0", "--imu-rate", str(IMU_HZ),
                           "--send", f"udpout:127.0.0.1:{udp}", "--truth", str(truth_file), "--start-at", f"+{LEAD_S}"])
    listener = tap = fuser = None
    can_report: dict = {}
    try:
        start_at = sender_start(sender)
        fuser = FuserThread(["run", "--mavlink", f"udpin:127.0.0.1:{udp}", "--can", f"virtual:{channel}", "--vehicle", vehicle,
                             "--config", str(config), "--zenoh-listen", endpoint, "--duration", f"{start_at - time.time() + flight_s + 0.3:.2f}"])
        fuser.start()
        wait_listening(zport)  # the fuser opens its links before zenoh: from now on nothing sent is lost
        listener = Proc(FUSER + ["listen", "--json", "--vehicle", vehicle, "--zenoh-connect", endpoint])
        tap = StatusTap(endpoint, vehicle)
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            can_report["report"] = send_flight(can_flight, can_bus=bus, start_at=start_at)
        finally:
            bus.shutdown()
        assert sender.wait(15) == 0, "".join(sender.err)
        fuser.finish(10)
        time.sleep(0.2)  # the last estimates in flight to the listener
    finally:
        stop_all((listener, sender), tap, fuser)

    report = sender.json_lines()[-1]
    assert report["max_late_ms"] < 100, f"sender could not keep pace: {report}"
    truth = np.load(truth_file)
    # the truth is the flight programme, independent of the sensor noise seed
    np.testing.assert_allclose(truth["q_wxyz"], can_flight.q_true, atol=1e-12)
    received = listener.json_lines()
    err = errors_of(received, truth)
    t0 = int(truth["t_ns"][0])
    # scenario 'aggressive' = programme 4-32 s: hover to 10 s (scored from 2 s: the filter starts uniform),
    # turns from 10 s, fast manoeuvres up to 500 deg/s from 25 s
    hover = window_rms(err, t0, 2.0, 6.0)
    manoeuvres = window_rms(err, t0, 21.0, flight_s - 0.5)
    overall = window_rms(err, t0, 2.0, flight_s - 0.5)
    status = tap.status[-1][1]
    mav = next(v for k, v in status["sources"].items() if k.startswith("mavlink:"))
    dcan = next(v for k, v in status["sources"].items() if k.startswith("can:"))
    print(f"\ne2e: {len(received)} estimates received; RMS error hover {hover:.2f} deg, fast manoeuvres {manoeuvres:.2f} deg, "
          f"whole aggressive flight {overall:.2f} deg; latency {status['latency']}; loop {status['loop']}; model {status['model']}; "
          f"runner {status['runner']}; mavlink {mav}; can {dcan}; sender {report}")
    assert hover < HOVER_RMS_BOUND_DEG
    assert overall < AGGRESSIVE_RMS_BOUND_DEG
    assert manoeuvres < MANOEUVRE_RMS_BOUND_DEG
    # both links delivered what was sent (the last status is at most a second old)
    assert mav["accepted"] > 0.9 * report["imu_sent"]
    assert dcan["accepted"] > 0.9 * can_report["report"].imu_sent
