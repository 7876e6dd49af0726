"""The three outputs from the command line: `bingham-fuser sim --ros2 --foxglove --mavlink-out` reaches a ROS 2
subscriber (through a router, settings from the TOML file), a ground station and a Foxglove client; a missing
package is one clear line naming the extra."""

from __future__ import annotations

import json
import os
import re
import socket
import struct
import sys
import threading
from pathlib import Path

import pytest

pytest.importorskip("rosbags")
pytest.importorskip("foxglove")
import zenoh  # noqa: E402

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

from fuser.cli import main  # noqa: E402
from local_net import free_port  # noqa: E402

SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


def _session(mode: str, **endpoints: list[str]) -> zenoh.Session:
    conf = {"mode": mode, "scouting": SCOUTING, **{k: {"endpoints": v} for k, v in endpoints.items()}}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


def test_sim_publishes_to_ros2_foxglove_and_a_ground_station(tmp_path: Path, capsys) -> None:
    router = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "fuser.toml"
    cfg.write_text(f'[fuser]\nrate_hz = 50\n[fuser.ros2]\ndomain_id = 7\nnamespace = "/drone1"\nrouter_endpoint = "{router}"\n'
                   '[fuser.mavlink_out]\nrate_hz = 5\ncomponent_id = 191\n'
                   '[fuser.extrapolation]\nevery_imu_sample = false\n')  # one estimate per tick: the counts below are the ticks'

    udp = free_port(socket.SOCK_DGRAM)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{udp}", dialect="common")
    r = _session("router", listen=[router])
    sub = _session("client", connect=[router])
    imu = []
    s = sub.declare_subscriber("7/drone1/bingham_fuser/attitude/sensor_msgs::msg::dds_::Imu_/*",
                               lambda x: imu.append((x.payload.to_bytes(), x.attachment.to_bytes())))
    heard: list = []
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            m = gcs.recv_match(blocking=True, timeout=0.1)
            if m is not None and m.get_type() in ("ATTITUDE_QUATERNION", "HEARTBEAT"):
                heard.append((m.get_type(), m.get_srcComponent()))

    t = threading.Thread(target=listen, daemon=True)
    t.start()
    try:
        code = main(["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "", "--config", str(cfg),
                     "--ros2", "--foxglove", "0", "--mavlink-out", f"udpout:127.0.0.1:{udp}"])
        assert code == 0
    finally:
        stop.set()
        t.join()
        s.undeclare()
        sub.close()
        r.close()
        gcs.close()
    # 12 s of hover at 50 Hz: every estimate published on ROS 2 (the sequence numbers count them; a burst this
    # fast may meet congestion control "drop" on a loaded machine), 5 Hz attitudes and 1 Hz heartbeats from 191
    seqs = [struct.unpack_from("<q", a)[0] for _, a in imu]
    captured = capsys.readouterr()
    estimates = int(re.search(r"-> (\d+) estimates", captured.out)[1])
    assert re.search(r"^foxglove: live view on ws://127\.0\.0\.1:[1-9]\d* ", captured.err, re.M), captured.err  # the port bound for 0
    assert 590 <= estimates <= 601 and imu and seqs == sorted(set(seqs)) and estimates - 10 <= seqs[-1] <= estimates
    assert all(p[:4] == b"\x00\x01\x00\x00" for p, _ in imu)
    counts = {k: sum(1 for h in heard if h[0] == k) for k in ("ATTITUDE_QUATERNION", "HEARTBEAT")}
    assert 59 <= counts["ATTITUDE_QUATERNION"] <= 61 and 11 <= counts["HEARTBEAT"] <= 13, counts
    assert {c for _, c in heard} == {191}


def test_a_missing_package_is_one_line_naming_the_extra(monkeypatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "rosbags", None)
    monkeypatch.setitem(sys.modules, "rosbags.typesys", None)
    assert main(["sim", "--scenario", "hover", "--speed", "0", "--no-zenoh", "-o", "", "--ros2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "bingham-fuser: --ros2 needs the 'rosbags' package: pip install 'bingham-fuser[ros2]'"


def test_with_ros2_the_fusers_own_keys_go_through_the_router_not_a_second_listener(tmp_path: Path) -> None:
    """`--ros2` with default zenoh endpoints: the bingham_fuser/<vehicle>/attitude estimates reach a client of the
    ROS 2 router (a listening peer of the fuser's own, the old default, would reach nobody connected there)."""
    router = f"tcp/127.0.0.1:{free_port()}"
    cfg = tmp_path / "fuser.toml"
    cfg.write_text(f'[fuser]\nrate_hz = 20\n[fuser.ros2]\nrouter_endpoint = "{router}"\n')
    r = _session("router", listen=[router])
    sub = _session("client", connect=[router])
    estimates: list = []
    s = sub.declare_subscriber("bingham_fuser/ros2veh/attitude", lambda x: estimates.append(json.loads(x.payload.to_bytes())))
    try:
        assert main(["sim", "--scenario", "hover", "--speed", "0", "-o", "", "--vehicle", "ros2veh", "--config", str(cfg), "--ros2"]) == 0
    finally:
        s.undeclare()
        sub.close()
        r.close()
    assert len(estimates) > 100 and all("q_wxyz" in e for e in estimates)

