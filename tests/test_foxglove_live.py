"""Foxglove live: a WebSocket client speaking Foxglove's protocol subscribes to every channel and decodes
the binary message frames with the schemas the server advertises (protobuf descriptors, JSON); the values
are checked against what was fed in. And the same frame tree in recordings, against Foxglove's schema."""

from __future__ import annotations

import base64
import json
import struct
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("foxglove")
websockets_client = pytest.importorskip("websockets.sync.client")
pytest.importorskip("google.protobuf")
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from drivers.samples import AttitudeSample, GnssSample, ImuSample  # noqa: E402
from fuser.codec import encode_sample  # noqa: E402
from fuser.foxglove_live import FoxgloveLive  # noqa: E402
from fuser.record import McapRecorder, read_log  # noqa: E402
from covariance_checks import assert_covariance_matches_rms  # noqa: E402

LOGS = Path(__file__).resolve().parent.parent / "logs"

# Foxglove's published JSON schema of foxglove.FrameTransforms (foxglove-sdk, schemas/jsonschema/
# FrameTransforms.json), its fields and types written out here as the independent check of what the
# recorder writes.
_XYZ = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}, "required": list("xyz")}
FOXGLOVE_FRAME_TRANSFORMS = {
    "type": "object",
    "properties": {"transforms": {"type": "array", "items": {
        "type": "object",
        "properties": {
            "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _XYZ,
            "rotation": {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}, "required": list("xyzw")},
        },
        "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
        "additionalProperties": False,
    }}},
    "required": ["transforms"],
    "additionalProperties": False,
}


def _feed(seconds: float) -> list[tuple[str, object, int]]:
    """The first seconds of a real fuser run (logs/sim_hover.mcap): inputs, truth and estimates, in time order."""
    c = read_log(LOGS / "sim_hover.mcap")
    events = [(r, "input", s) for s, r in c.inputs()] + [(t, "truth", q) for t, q in c.truth()]
    events += [(e.t_ns, "estimate", e) for e in c.estimates()]
    events.sort(key=lambda x: x[0])
    t0 = events[0][0]
    return [(kind, obj, t) for t, kind, obj in events if t - t0 < seconds * 1e9]


def _decoder(channel: dict):
    """A function bytes -> message for an advertised channel, from its advertised schema alone."""
    if channel["encoding"] == "json":
        return json.loads
    assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"])).FromString


def _stamp_ns(ts) -> int:
    return ts.seconds * 1_000_000_000 + ts.nanos


@pytest.mark.parametrize("offered", [["foxglove.sdk.v1"], ["foxglove.websocket.v1", "foxglove.sdk.v1"]])
def test_a_foxglove_client_subscribes_and_decodes_every_channel(offered: list[str]) -> None:
    fox = FoxgloveLive(port=0)
    assert fox.port and fox.error is None
    try:
        with websockets_client.connect(f"ws://127.0.0.1:{fox.port}", subprotocols=offered) as ws:
            assert ws.subprotocol == "foxglove.sdk.v1"  # foxglove-sdk 0.30 speaks sdk.v1, also to clients offering both
            info = json.loads(ws.recv(timeout=5))
            assert info["op"] == "serverInfo" and info["name"] == "bingham-fuser"
            channels: dict[int, dict] = {}
            while len(channels) < 11:
                msg = json.loads(ws.recv(timeout=5))
                assert msg["op"] == "advertise"
                channels.update({c["id"]: c for c in msg["channels"]})
            by_topic = {c["topic"]: c for c in channels.values()}
            assert {t: c["schemaName"] for t, c in by_topic.items() if c["encoding"] == "protobuf"} == {
                "/tf": "foxglove.FrameTransforms", "/pose": "foxglove.PoseInFrame",
                "/truth/pose": "foxglove.PoseInFrame", "/reference/pose": "foxglove.PoseInFrame"}
            subs = {100 + i: c for i, c in enumerate(channels.values())}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c["id"]} for s, c in subs.items()]}))
            deadline = time.monotonic() + 5
            while len(fox.subscribed_topics()) < len(subs):
                assert time.monotonic() < deadline, "subscriptions never reached the server"
                time.sleep(0.01)

            feed = _feed(0.5)  # about 450 messages: well inside the server's 1024-message backlog per client
            expected: list[tuple[str, int, object]] = []
            for kind, obj, t in feed:
                if kind == "input":
                    fox.write_sample(obj, t)
                    expected.append((f"/input/{ {ImuSample: 'imu', AttitudeSample: 'attitude', GnssSample: 'gnss'}[type(obj)] }", t, obj))
                    if isinstance(obj, AttitudeSample):
                        expected += [("/tf", t, ("reference_body", obj.q_wxyz)), ("/reference/pose", t, obj.q_wxyz)]
                elif kind == "truth":
                    fox.write_truth(t, obj)
                    expected += [("/tf", t, ("truth_body", obj)), ("/truth/pose", t, obj)]
                else:
                    fox.write_estimate(obj)
                    expected += [("/tf", t, ("body", obj.q_wxyz)), ("/pose", t, obj.q_wxyz), ("/estimate", t, obj), ("/uncertainty", t, obj)]
            status = {"estimates": 3, "loop": {"late": 1}}
            fox.write_status(feed[-1][2], status)
            expected.append(("/status", feed[-1][2], status))
            assert fox.errors == 0

            received: list[tuple[str, int, object]] = []
            decoders = {s: _decoder(c) for s, c in subs.items()}
            while len(received) < len(expected):
                frame = ws.recv(timeout=5)
                if isinstance(frame, str):
                    continue  # e.g. a status or advertise message
                opcode, sub_id, log_time = struct.unpack_from("<BIQ", frame, 0)
                assert opcode == 0x01  # Message Data
                received.append((subs[sub_id]["topic"], log_time, decoders[sub_id](frame[13:])))
    finally:
        fox.close()

    # per topic, in order (the server may interleave topics)
    for topic in {t for t, _, _ in expected}:
        exp = [(t, o) for top, t, o in expected if top == topic]
        got = [(t, m) for top, t, m in received if top == topic]
        assert len(got) == len(exp) > 0, topic
        for (t, obj), (log_time, m) in zip(exp, got, strict=True):
            assert log_time == t
            if topic == "/tf":
                child, q = obj
                (ned, body) = m.transforms
                assert (ned.parent_frame_id, ned.child_frame_id, body.parent_frame_id, body.child_frame_id) == ("enu", "ned", "ned", child)
                up = Rotation.from_quat([ned.rotation.x, ned.rotation.y, ned.rotation.z, ned.rotation.w])
                np.testing.assert_allclose(up.apply([[1, 0, 0], [0, 1, 0], [0, 0, 1]]), [[0, 1, 0], [1, 0, 0], [0, 0, -1]], atol=1e-12)
                np.testing.assert_allclose([body.rotation.w, body.rotation.x, body.rotation.y, body.rotation.z], q, rtol=0, atol=0)
                offset = [body.translation.x, body.translation.y, body.translation.z]
                assert offset == ([0.0, 0.0, 0.0] if child == "body" else [0.0, 1.0, 0.0])  # truth and reference 1 m east
                assert _stamp_ns(body.timestamp) == t
            elif topic.endswith("/pose"):
                o = m.pose.orientation
                assert m.frame_id == "ned" and [o.w, o.x, o.y, o.z] == list(obj) and _stamp_ns(m.timestamp) == t
                assert m.pose.position.y == (0.0 if topic == "/pose" else 1.0)
            elif topic == "/estimate":
                assert m == json.loads(obj.to_json())
            elif topic == "/uncertainty":
                assert m["rms_deg"] == obj.uncertainty_deg
                cov = np.reshape(m["covariance_ned_rad2"], (3, 3))
                assert_covariance_matches_rms(cov, obj.uncertainty_deg)
                np.testing.assert_allclose(np.radians(m["sigma_ned_deg"]) ** 2, np.diag(cov), rtol=1e-12)
            elif topic.startswith("/input/"):
                assert m == json.loads(json.dumps(encode_sample(obj, t)))
            else:
                assert m == obj


def test_recordings_carry_the_same_frame_tree_valid_for_foxglove(tmp_path: Path) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    c = read_log(LOGS / "sim_hover.mcap")
    est = [e for e in c.estimates() if not e.predicted][:5]  # a tick's estimate has a frame; the predictor's are on /estimate only
    assert [e for e in c.estimates()[:20] if e.predicted]
    truth = c.truth()[:5]
    with McapRecorder(tmp_path / "x.mcap") as rec:
        for e in est:
            rec.write_estimate(e)
        for t, q in truth:
            rec.write_truth(t, q)
    log = read_log(tmp_path / "x.mcap")
    tf = log.topic("/tf")
    assert len(tf) == len(est) + len(truth)
    for _, msg in tf:
        jsonschema.validate(msg, FOXGLOVE_FRAME_TRANSFORMS)
    children = {m["transforms"][1]["child_frame_id"]: m for _, m in tf}
    assert set(children) == {"body", "truth_body"}
    assert children["truth_body"]["transforms"][1]["translation"] == {"x": 0.0, "y": 1.0, "z": 0.0}
    poses = dict(log.topic("/truth/pose"))
    assert all(p["pose"]["position"] == {"x": 0.0, "y": 1.0, "z": 0.0} for p in poses.values())  # apart from /pose
    for (t, msg), e in zip((x for x in tf if x[1]["transforms"][1]["child_frame_id"] == "body"), est, strict=True):
        r = msg["transforms"][1]["rotation"]
        assert t == e.t_ns and [r["w"], r["x"], r["y"], r["z"]] == list(e.q_wxyz)


def test_a_taken_port_is_reported_once_and_never_raises() -> None:
    first = FoxgloveLive(port=0)
    try:
        second = FoxgloveLive(port=first.port)
        second.write_estimate(read_log(LOGS / "sim_hover.mcap").estimates()[0])
        assert second.port is None and second.errors == 2 and "cannot serve" in second.error
        second.close()
    finally:
        first.close()
