"""ROS 2 over rmw_zenoh: keys, CDR payloads, attachments and liveliness tokens checked against the
documented format of rmw_zenoh_cpp (Jazzy, 0.2.4+) with decoders written here, not the publisher's own.

No ROS installation exists here: the router is a zenoh session in router mode (as rmw_zenohd is), the
"ROS node" on the other side is a plain zenoh client that decodes what a ROS 2 subscriber would.
"""

from __future__ import annotations

import json
import re
import struct
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("xxhash")
import xxhash  # noqa: E402
import zenoh  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from core import quaternion as quat  # noqa: E402
from core.bingham import Bingham  # noqa: E402
from drivers.samples import ImuSample  # noqa: E402
from fuser.frames import R_ENU_NED, enu_flu_from_ned_frd, orientation_covariance_enu, orientation_covariance_ned  # noqa: E402
from fuser.record import read_log  # noqa: E402
from covariance_checks import assert_covariance_matches_rms  # noqa: E402
from fuser.ros2 import IMU_TYPE, POSE_TYPE, Ros2Publisher, Ros2Settings, resolve_topic  # noqa: E402
from local_net import free_port, wait_for  # noqa: E402

LOGS = Path(__file__).resolve().parent.parent / "logs"

# RIHS01 type hashes as ROS 2 Jazzy itself publishes them (REP-2011 type descriptions installed by
# the message packages, /opt/ros/jazzy/share/<pkg>/msg/<Type>.json): Imu, Header and String as listed
# in CARLA's golden-hash test (extracted from osrf/ros:jazzy-desktop), String also in rmw_zenoh's
# docs/design.md example key; PoseWithCovarianceStamped as in the rosidl-generated type tables of
# several ROS 2 zenoh bridges built against Jazzy.
JAZZY_HASHES = {
    "sensor_msgs/msg/Imu": "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    "std_msgs/msg/Header": "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
}

SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


def session(mode: str, **endpoints: list[str]) -> zenoh.Session:
    conf = {"mode": mode, "scouting": SCOUTING, **{k: {"endpoints": v} for k, v in endpoints.items()}}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(conf)))


@pytest.fixture
def router():
    """A zenoh router on a free port, standing in for rmw_zenohd on 7447."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = session("router", listen=[endpoint])
    yield endpoint
    r.close()


def test_type_hashes_are_the_ones_ros2_jazzy_publishes() -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    for name, expected in JAZZY_HASHES.items():
        assert store.hash_rihs01(name) == expected, name


def test_frames_follow_rep_103() -> None:
    # level, nose north: FLU x (forward) is ENU north = +y, a +90 deg yaw about ENU up
    np.testing.assert_allclose(enu_flu_from_ned_frd([1, 0, 0, 0]), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    # nose east: FLU is aligned with ENU
    q_east = quat.from_axis_angle([0, 0, 1], np.pi / 2)  # yaw +90 deg about NED down
    np.testing.assert_allclose(enu_flu_from_ned_frd(q_east), [1, 0, 0, 0], atol=1e-15)
    # any attitude: forward, left and up of the body, expressed in ENU by hand
    rng = np.random.default_rng(3)
    for q in quat.normalize(rng.standard_normal((20, 4))):
        q_enu_flu = enu_flu_from_ned_frd(q)
        fwd_ned, right_ned, down_ned = quat.rotate(q, np.eye(3))
        enu = lambda v: np.array([v[1], v[0], -v[2]])  # noqa: E731 - x east, y north, z up
        np.testing.assert_allclose(quat.rotate(q_enu_flu, [1, 0, 0]), enu(fwd_ned), atol=1e-12)
        np.testing.assert_allclose(quat.rotate(q_enu_flu, [0, 1, 0]), enu(-right_ned), atol=1e-12)
        np.testing.assert_allclose(quat.rotate(q_enu_flu, [0, 0, 1]), enu(-down_ned), atol=1e-12)


@pytest.mark.parametrize("method", ["saddlepoint", "exact"])
def test_orientation_covariance_matches_a_monte_carlo_of_the_bingham(method: str) -> None:
    """Covariance of the world-frame error rotation of exact Bingham draws (core.sampling) against the closed form."""
    rng = np.random.default_rng(11)
    mode = quat.normalize([0.8, -0.2, 0.35, 0.44])
    b = Bingham.from_mode(mode, [-3000.0, -900.0, -250.0])  # anisotropic, 1.3 to 3.6 degrees
    draws = b.sample(40_000, rng)
    err_ned = quat.to_rotvec(quat.multiply(draws, quat.conjugate(mode)))  # q = exp(delta) (x) mode
    mc_ned = err_ned.T @ err_ned / len(err_ned)
    closed = orientation_covariance_ned(b.M, b.Z, mode, method)
    # relative error of the covariance matrix (Frobenius): MC noise ~ sqrt(2/n) = 0.7%, saddlepoint moments 1.2%
    assert np.linalg.norm(closed - mc_ned) / np.linalg.norm(mc_ned) < (0.03 if method == "saddlepoint" else 0.02)
    # the principal variances differ by a factor 12: the check sees axes, not just the total
    assert np.linalg.eigvalsh(mc_ned)[-1] / np.linalg.eigvalsh(mc_ned)[0] > 8
    err_enu = err_ned @ R_ENU_NED.T
    mc_enu = err_enu.T @ err_enu / len(err_enu)
    closed_enu = orientation_covariance_enu(b.M, b.Z, mode, method)
    assert np.linalg.norm(closed_enu - mc_enu) / np.linalg.norm(mc_enu) < 0.03


def test_settings_are_validated_with_the_key_named() -> None:
    for kwargs, key in [({"domain_id": 300}, "ros2.domain_id"), ({"namespace": "drone"}, "ros2.namespace"),
                        ({"namespace": "/a//b"}, "ros2.namespace"), ({"node_name": "9lives"}, "ros2.node_name"),
                        ({"imu_topic": "att itude"}, "ros2.imu_topic"), ({"pose_topic": "/x/"}, "ros2.pose_topic"),
                        ({"body_frame_id": ""}, "ros2.body_frame_id"), ({"connect_to_router": False}, "ros2.listen")]:
        with pytest.raises(ValueError, match=re.escape(key)):
            Ros2Settings(**kwargs)
    assert resolve_topic("~/attitude", "/", "bingham_fuser") == "/bingham_fuser/attitude"
    assert resolve_topic("~/attitude", "/drone1", "fuser") == "/drone1/fuser/attitude"
    assert resolve_topic("imu", "/drone1", "fuser") == "/drone1/imu"
    assert resolve_topic("/imu", "/drone1", "fuser") == "/imu"


def _cdr_imu(payload: bytes) -> dict:
    """Decode a CDR sensor_msgs/Imu by hand: encapsulation header, then fields aligned to their size
    relative to the end of the header (OMG CDR / XCDR1, as Fast-CDR writes it)."""
    assert payload[:4] == b"\x00\x01\x00\x00"  # CDR_LE, options 0
    body = payload[4:]
    sec, nanosec, n = struct.unpack_from("<iII", body, 0)
    frame_id = body[12 : 12 + n]
    assert frame_id.endswith(b"\x00")
    pos = 12 + n
    pos += -pos % 8
    doubles = struct.unpack_from("<37d", body, pos)
    assert pos + 37 * 8 == len(body)
    return {"sec": sec, "nanosec": nanosec, "frame_id": frame_id[:-1].decode(), "orientation_xyzw": doubles[0:4],
            "orientation_covariance": doubles[4:13], "angular_velocity": doubles[13:16],
            "angular_velocity_covariance": doubles[16:25], "linear_acceleration": doubles[25:28],
            "linear_acceleration_covariance": doubles[28:37]}


def _attachment(raw: bytes) -> tuple[int, int, bytes]:
    """rmw_zenoh_cpp >= 0.2.4: int64 LE sequence number, int64 LE source timestamp, LEB128 length 16, 16-byte GID."""
    assert len(raw) == 33
    seq, stamp_ns, length = struct.unpack_from("<qqB", raw, 0)
    assert length == 16
    return seq, stamp_ns, raw[17:]


def _log_feed() -> list[tuple[str, object]]:
    """The first 2 s of a real fuser run (logs/sim_hover.mcap): IMU samples and estimates in time order."""
    contents = read_log(LOGS / "sim_hover.mcap")
    events = [(r, "imu", s) for s, r in contents.inputs() if isinstance(s, ImuSample)]
    events += [(e.t_ns, "est", e) for e in contents.estimates()]
    events.sort(key=lambda x: (x[0], x[1] == "est"))
    t0 = events[0][0]
    return [(kind, obj) for t, kind, obj in events if t - t0 < 2_000_000_000]


def test_a_ros2_subscriber_receives_imu_and_pose_as_rmw_zenoh_sends_them(router: str) -> None:
    settings = Ros2Settings(enabled=True, router_endpoint=router)
    imu_key = f"0/bingham_fuser/attitude/sensor_msgs::msg::dds_::Imu_/{JAZZY_HASHES[IMU_TYPE]}"
    pose_key = f"0/bingham_fuser/pose/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/{JAZZY_HASHES[POSE_TYPE]}"
    sub = session("client", connect=[router])
    got: dict[str, list] = {imu_key: [], pose_key: []}
    subs = [sub.declare_subscriber(k, lambda s, k=k: got[k].append((s.payload.to_bytes(), s.attachment.to_bytes())))
            for k in got]
    pub = Ros2Publisher(settings)
    try:
        assert pub.error is None and pub.keys == {IMU_TYPE: imu_key, POSE_TYPE: pose_key}
        # graph discovery: the node and its two publishers, as rmw_zenoh's liveliness tokens
        zid = pub.zid
        tokens: set[str] = set()
        deadline = time.monotonic() + 10
        while len(tokens) < 3 and time.monotonic() < deadline:  # the router learns of them asynchronously
            tokens = {str(r.ok.key_expr) for r in sub.liveliness().get("@ros2_lv/0/**", timeout=5.0)}
        assert re.fullmatch(r"[0-9a-f]{2,32}", zid)
        qos = "::,10:,:,:,,"
        expected_tokens = {
            f"@ros2_lv/0/{zid}/0/0/NN/%/%/bingham_fuser",
            f"@ros2_lv/0/{zid}/0/10/MP/%/%/bingham_fuser/%bingham_fuser%attitude/sensor_msgs::msg::dds_::Imu_/"
            f"{JAZZY_HASHES[IMU_TYPE]}/{qos}",
            f"@ros2_lv/0/{zid}/0/11/MP/%/%/bingham_fuser/%bingham_fuser%pose/"
            f"geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/{JAZZY_HASHES[POSE_TYPE]}/{qos}",
        }
        assert tokens == expected_tokens
        imu_token = next(t for t in tokens if "Imu_" in t)

        sent, last_imu = [], None
        before_ns = time.time_ns()
        for kind, obj in _log_feed():
            if kind == "imu":
                pub.write_sample(obj, 0)
                last_imu = obj
            else:
                pub.publish_estimate(obj)
                sent.append((obj, last_imu))
                # in lockstep: a burst far faster than real time would meet congestion control "drop", as rmw_zenoh's does
                wait_for(lambda: len(got[imu_key]) == len(got[pose_key]) == len(sent))
        after_ns = time.time_ns()
        assert pub.errors == 0 and pub.published == 2 * len(sent) > 300

        store = get_typestore(Stores.ROS2_JAZZY)
        for i, ((est, imu), (payload, raw_att)) in enumerate(zip(sent, got[imu_key], strict=True)):
            seq, stamp_ns, gid = _attachment(raw_att)
            assert seq == i + 1
            assert before_ns <= stamp_ns <= after_ns
            h = xxhash.xxh3_128_intdigest(imu_token.encode())
            assert gid == struct.pack("<QQ", h & (2**64 - 1), h >> 64)  # XXH3-128 of the token, low half first
            m = _cdr_imu(payload)
            assert (m["sec"], m["nanosec"]) == divmod(est.t_ns, 10**9) and m["frame_id"] == "base_link"
            x, y, z, w = m["orientation_xyzw"]
            # the body's forward axis points where the estimate says, in ENU
            fwd_ned = quat.rotate(est.q_wxyz, [1.0, 0.0, 0.0])
            np.testing.assert_allclose(quat.rotate([w, x, y, z], [1.0, 0.0, 0.0]), [fwd_ned[1], fwd_ned[0], -fwd_ned[2]], atol=1e-9)
            cov = np.reshape(m["orientation_covariance"], (3, 3))
            np.testing.assert_allclose(cov, cov.T, atol=1e-15)
            # its trace is the mean squared angle, whose root the estimate reports as uncertainty_deg
            assert_covariance_matches_rms(cov, est.uncertainty_deg)
            if imu is None:
                assert m["angular_velocity_covariance"][0] == -1.0  # "no estimate"
            else:
                gx, gy, gz = imu.gyro_rad_s
                ax, ay, az = imu.accel_m_s2
                assert m["angular_velocity"] == (gx, -gy, -gz) and m["linear_acceleration"] == (ax, -ay, -az)
                assert m["angular_velocity_covariance"] == (0.0,) * 9  # "unknown"
            decoded = store.deserialize_cdr(payload, IMU_TYPE)
            assert decoded.orientation.w == w and list(decoded.orientation_covariance) == list(m["orientation_covariance"])
        # hovering: the accelerometer reads +g up in FLU, on average
        up = [_cdr_imu(p)["linear_acceleration"][2] for p, _ in got[imu_key][1:]]
        assert np.mean(up) == pytest.approx(9.8, abs=0.3)
        for (est, _), (payload, raw_att) in zip(sent, got[pose_key], strict=True):
            pose = store.deserialize_cdr(payload, POSE_TYPE)
            assert pose.header.frame_id == "world" and (pose.header.stamp.sec, pose.header.stamp.nanosec) == divmod(est.t_ns, 10**9)
            c = np.reshape(pose.pose.covariance, (6, 6))
            np.testing.assert_allclose(c[3:, 3:], orientation_covariance_enu(est.M, est.Z, est.q_wxyz), rtol=1e-12)
            assert np.all(np.diag(c)[:3] >= 1e6)  # position: not estimated
        assert [_attachment(a)[0] for _, a in got[pose_key]] == list(range(1, len(sent) + 1))
    finally:
        pub.close()
        for s in subs:
            s.undeclare()
        sub.close()


def test_without_a_router_it_counts_errors_and_connects_once_one_starts(monkeypatch) -> None:
    from fuser import ros2

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    monkeypatch.setattr(ros2, "ROUTER_RETRY_S", 0.0)
    pub = Ros2Publisher(Ros2Settings(router_endpoint=endpoint))
    est = read_log(LOGS / "sim_hover.mcap").estimates()[0]
    pub.publish_estimate(est)  # must not raise
    assert pub.errors >= 2 and pub.published == 0 and "router" in pub.error
    r = session("router", listen=[endpoint])
    try:
        pub.publish_estimate(est)
        assert pub.published == 2
    finally:
        pub.close()
        r.close()
