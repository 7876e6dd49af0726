"""MCAP recording: exact round trip, byte-identical output, and recovery after SIGKILL or truncation."""

from __future__ import annotations

import json
import logging
import os
import random
import signal
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from drivers.samples import AttitudeSample, ImuSample, MagSample, SourceId
from fuser.codec import Estimate
from fuser.record import CHANNELS, DIAGNOSTICS, McapRecorder, NotAnMcapError, RecorderProcess, read_log

LOGS = Path(__file__).resolve().parent.parent / "logs"

MAV = SourceId("mavlink", 1, 1, 0)
CAN = SourceId("dronecan", 42, 0, 1)


def _vec(rng: random.Random, n: int) -> tuple[float, ...]:
    return tuple(rng.uniform(-10, 10) for _ in range(n))


def make_calls(n: int = 40, seed: int = 1) -> list[tuple[str, tuple]]:
    """A mixed, reproducible sequence of recorder calls covering every sample type."""
    rng = random.Random(seed)
    calls: list[tuple[str, tuple]] = []
    for i in range(n):
        t = 1_000_000_000 + i * 2_500_000
        calls.append(("write_sample", (ImuSample(t, _vec(rng, 3), _vec(rng, 3), _vec(rng, 3), MAV), t + 7)))
        calls.append(("write_sample", (ImuSample(t + 1, _vec(rng, 3), _vec(rng, 3), None, CAN), t + 8)))
        calls.append(("write_sample", (MagSample(t + 2, _vec(rng, 3), CAN), t + 9)))
        calls.append(("write_sample", (AttitudeSample(t + 3, _vec(rng, 4), MAV), t + 10)))
        if i % 4 == 3:
            m = tuple(_vec(rng, 4) for _ in range(4))
            est = Estimate(t + 11, _vec(rng, 4), m, (0.0, -rng.uniform(1, 1e4), -2e4, -3e4), rng.random(), _vec(rng, 3), {"ticks": i, "late": 2})
            calls.append(("write_estimate", (est,)))
            calls.append(("write_truth", (t + 11, _vec(rng, 4))))
            calls.append(("write_status", (t + 11, {"ticks": i, "ok": True})))
    return calls


def record(path: Path, calls: list[tuple[str, tuple]], **kw) -> None:
    with McapRecorder(path, **kw) as rec:
        for method, args in calls:
            getattr(rec, method)(*args)


def expected_messages(calls: list[tuple[str, tuple]]) -> list[tuple[str, int, object]]:
    """What read_log must return for ``calls``, built from the call arguments (log-time order)."""
    out: list[tuple[str, int, object]] = []
    for method, args in calls:
        if method == "write_sample":
            out.append(("input", args[1], args))
        elif method == "write_estimate":
            out.append(("/estimate", args[0].t_ns, args[0]))
        elif method == "write_truth":
            out.append(("/truth/pose", args[0], args[1]))
        else:
            out.append(("/status", args[0], args[1]))
    return sorted(out, key=lambda m: m[1])


def test_round_trip_every_type_reads_back_equal(tmp_path: Path) -> None:
    calls = make_calls()
    path = tmp_path / "a.mcap"
    record(path, calls, metadata={"vehicle": "v1", "rate_hz": "100"})
    log = read_log(path)
    assert log.complete and log.error is None
    assert log.metadata == {"bingham_fuser": {"rate_hz": "100", "vehicle": "v1"}}
    exp = expected_messages(calls)
    assert log.inputs() == [args for kind, _, args in exp if kind == "input"]
    assert log.estimates() == [e for kind, _, e in exp if kind == "/estimate"]
    assert log.truth() == [(t, q) for kind, t, q in exp if kind == "/truth/pose"]
    assert log.status() == [(t, s) for kind, t, s in exp if kind == "/status"]
    times = [t for _, t, _ in log.messages]
    assert times == sorted(times)
    # /pose mirrors /estimate as a Foxglove PoseInFrame, orientation in x, y, z, w order.
    for (t, pose), est in zip(log.topic("/pose"), log.estimates(), strict=True):
        w, x, y, z = est.q_wxyz
        assert t == est.t_ns
        assert pose == {
            "timestamp": {"sec": t // 10**9, "nsec": t % 10**9},
            "frame_id": "ned",
            "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": x, "y": y, "z": z, "w": w}},
        }


def test_complete_file_has_schemas_and_validates(tmp_path: Path) -> None:
    jsonschema = pytest.importorskip("jsonschema")
    path = tmp_path / "a.mcap"
    record(path, make_calls(8))
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert sorted(topics) == sorted(CHANNELS)
        assert topics["/pose"].name == topics["/truth/pose"].name == "foxglove.PoseInFrame"
        assert all(s.encoding == "jsonschema" for s in topics.values())
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        n = 0
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            n += 1
    assert n == read_log(path).records == summary.statistics.message_count


def _required(schema: dict, path: str = "") -> dict[str, list[str] | None]:
    """Every object of a JSON schema (by its path) and the fields it requires (None: it lists none)."""
    out: dict[str, list[str] | None] = {}
    if schema.get("type") == "object":
        out[path or "."] = schema.get("required")
        for name, sub in schema.get("properties", {}).items():
            out |= _required(sub, f"{path}.{name}")
    if schema.get("type") == "array" and isinstance(schema.get("items"), dict):
        out |= _required(schema["items"], f"{path}[]")
    return out


# Foxglove's published schemas (github.com/foxglove/foxglove-sdk, schemas/jsonschema/PoseInFrame.json and
# FrameTransforms.json), the fields we write: every object requires its fields, but the time, which lists none.
FOXGLOVE_REQUIRED = {
    "foxglove.PoseInFrame": {".": ["timestamp", "frame_id", "pose"], ".timestamp": None, ".pose": ["position", "orientation"],
                             ".pose.position": ["x", "y", "z"], ".pose.orientation": ["x", "y", "z", "w"]},
    "foxglove.FrameTransforms": {".": ["transforms"], ".transforms[]": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
                                 ".transforms[].timestamp": None, ".transforms[].translation": ["x", "y", "z"],
                                 ".transforms[].rotation": ["x", "y", "z", "w"]},
}


def test_foxglove_schemas_require_what_foxgloves_own_do() -> None:
    """Ours added required sec and nsec to the timestamp, which Foxglove's do not have."""
    for topic in ("/pose", "/truth/pose", "/tf"):
        schema = CHANNELS[topic]
        assert _required(schema) == FOXGLOVE_REQUIRED[schema["title"]], topic
    time = CHANNELS["/pose"]["properties"]["timestamp"]
    assert (time["title"], time["properties"]) == ("time", {"sec": {"type": "integer", "minimum": 0},
                                                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}})


def test_diagnostics_schema_names_every_update_the_model_reports() -> None:
    """It described ``update`` as gravity, heading or attitude, though velocity and mag_field occur too (in every flight
    with GNSS); each update's diagnostic of a recorded flight validates against it."""
    jsonschema = pytest.importorskip("jsonschema")
    from fuser.model.diagnostics import UPDATES

    update = DIAGNOSTICS["properties"]["updates"]["items"]["properties"]["update"]
    assert sorted(update["enum"]) == sorted({*UPDATES, "mag_field"})
    assert all(name in update["description"] for name in update["enum"])
    seen = set()
    for _, record in read_log(LOGS / "sim_aggressive.mcap").topic("/diagnostics"):
        jsonschema.validate(record, DIAGNOSTICS)
        seen |= {d["update"] for d in record["updates"]}
    assert seen == {"mag_field", "velocity", "gravity", "heading"}  # the simulator sends no attitude the policy fuses


def test_same_calls_give_identical_bytes(tmp_path: Path) -> None:
    calls = make_calls(200)
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    record(a, calls, chunk_size=4096, metadata={"k": "v"})
    time.sleep(0.01)  # a wall-clock stamp anywhere would now differ
    record(b, calls, chunk_size=4096, metadata={"k": "v"})
    assert a.read_bytes() == b.read_bytes()
    record(b, make_calls(200, seed=2), chunk_size=4096, metadata={"k": "v"})
    assert a.read_bytes() != b.read_bytes()


def test_recorder_process_writes_the_same_file(tmp_path: Path) -> None:
    calls = make_calls(100)
    record(tmp_path / "direct.mcap", calls, chunk_size=4096)
    with RecorderProcess(tmp_path / "child.mcap", chunk_size=4096) as rp:
        for method, args in calls:
            getattr(rp, method)(*args)
    assert rp.dropped == 0 and not rp.alive
    assert rp.records_on_disk == read_log(tmp_path / "child.mcap").records
    assert (tmp_path / "child.mcap").read_bytes() == (tmp_path / "direct.mcap").read_bytes()


def imu(i: int) -> ImuSample:
    return ImuSample(i * 2_500_000, (i * 1e-3, 0.5, -0.25), (0.1, 0.2, -9.81), None, MAV)


def test_sigkill_loses_only_the_open_chunk_and_never_blocks_the_caller(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    rp = RecorderProcess(path, chunk_size=2048)
    for i in range(3000):
        rp.write_sample(imu(i), i * 2_500_000)
    deadline = time.monotonic() + 10
    while rp.records_on_disk < 1000 and time.monotonic() < deadline:
        time.sleep(0.0005)
    on_disk = rp.records_on_disk  # several chunks on disk, the child still writing
    assert on_disk >= 1000
    os.kill(rp.pid, signal.SIGKILL)
    while rp.alive and time.monotonic() < deadline:
        time.sleep(0.001)
    assert not rp.alive
    t0 = time.perf_counter()
    for i in range(3000, 5000):
        rp.write_sample(imu(i), i * 2_500_000)
    assert time.perf_counter() - t0 < 0.5  # no blocking on a dead child
    assert rp.dropped == 2000 and rp.submitted == 3000
    assert rp.close() is False

    log = read_log(path)
    assert not log.complete and log.error
    assert on_disk <= log.records <= 3000
    assert log.inputs() == [(imu(i), i * 2_500_000) for i in range(log.records)]


def test_truncated_copies_recover_a_prefix_without_exception(tmp_path: Path) -> None:
    calls = make_calls(300)
    full_path = tmp_path / "full.mcap"
    record(full_path, calls, chunk_size=2048)
    data = full_path.read_bytes()
    full = read_log(full_path)
    cut_path = tmp_path / "cut.mcap"
    for cut in (0, 3):  # not even the magic: nothing says this was ever a log
        cut_path.write_bytes(data[:cut])
        with pytest.raises(NotAnMcapError):
            read_log(cut_path)
    recovered = {}
    for cut in (8, 30, 200, len(data) // 4, len(data) // 2, 3 * len(data) // 4, len(data) - 200, len(data) - 1):
        cut_path.write_bytes(data[:cut])
        log = read_log(cut_path)
        assert not log.complete and log.error, cut
        assert log.messages == full.messages[: log.records], cut
        recovered[cut] = log.records
    counts = list(recovered.values())
    assert counts == sorted(counts) and counts[0] == 0
    assert 0 < recovered[len(data) // 2] < full.records
    assert recovered[len(data) - 1] == full.records  # only the closing magic is missing


@pytest.mark.parametrize("options", [{"compression": CompressionType.LZ4}, {"compression": CompressionType.NONE}, {"use_chunking": False}],
                         ids=["lz4", "uncompressed", "unchunked"])
def test_logs_of_other_writers_read_like_mcaps_own_reader(tmp_path: Path, options: dict) -> None:
    """read_log parses chunks itself: it must agree with mcap's reader on any chunk layout."""
    path = tmp_path / "other.mcap"
    rng = random.Random(3)
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=1024, **options)
        writer.start()
        schema = writer.register_schema("s", "jsonschema", b"{}")
        channels = {topic: writer.register_channel(topic, "json", schema) for topic in ("/input/imu", "/status")}
        for i in range(500):
            topic = rng.choice(list(channels))
            writer.add_message(channels[topic], rng.randint(0, 10**9), json.dumps({"i": i}).encode(), i, i)
        writer.finish()
    with open(path, "rb") as f:
        expected = [(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=True)]
    log = read_log(path)
    assert log.complete
    assert [tuple(m) for m in log.raw] == expected


def unstorable_calls() -> list[tuple[str, tuple]]:
    """Records a recorder cannot store, as a hostile link or a diverged filter would hand them over."""
    nan_est = Estimate(5_000, (1.0, 0.0, 0.0, 0.0), ((1.0, 0.0, 0.0, 0.0),) * 4, (0.0, -1.0, -1.0, -1.0), float("nan"), (0.0, 0.0, 0.0))
    return [
        ("write_sample", (ImuSample(2**63 * 1000, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, MAV), 1_000)),  # time_usec = 2^63
        ("write_sample", (ImuSample(1_000, (0.0, 0.0, 0.0), (0.0, 0.0, -9.81), None, MAV), -5)),  # before the epoch
        ("write_sample", (ImuSample(1_000, (float("nan"), 0.0, 0.0), (0.0, 0.0, -9.81), None, MAV), 2_000)),
        ("write_sample", (MagSample(1_000, (float("inf"), 0.0, 0.0), MAV), 2_000)),
        ("write_estimate", (nan_est,)),
        ("write_truth", (2**64, (1.0, 0.0, 0.0, 0.0))),
    ]


UNSTORABLE = {"time_out_of_range": 3, "not_json": 3}


def interleave(good: list, bad: list) -> list:
    step = len(good) // (len(bad) + 1)
    out = list(good)
    for i, call in enumerate(bad):
        out.insert((i + 1) * step + i, call)
    return out


def test_records_that_cannot_be_stored_are_counted_and_the_rest_is_intact(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    good = make_calls(60)
    path = tmp_path / "a.mcap"
    with caplog.at_level(logging.WARNING, logger="fuser.record"), McapRecorder(path, chunk_size=2048) as rec:
        for method, args in interleave(good, unstorable_calls()):
            getattr(rec, method)(*args)
    assert rec.rejected == UNSTORABLE
    assert len(caplog.records) == 1 and "recorder.rejected" in caplog.records[0].getMessage()  # said once, then counted
    # the file is complete and holds exactly the good records: read by mcap's own reader (CRCs checked)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        stored = [(c.topic, m.log_time, json.loads(m.data)) for _, c, m in reader.iter_messages(log_time_order=True)]
    record(tmp_path / "good.mcap", good, chunk_size=2048)
    assert path.read_bytes() == (tmp_path / "good.mcap").read_bytes()
    # beside each estimate its /pose and /tf, beside each truth its /tf
    extra = sum(2 if m == "write_estimate" else m == "write_truth" for m, _ in good)
    assert len(stored) == read_log(path).records == len(expected_messages(good)) + extra


def test_recorder_process_outlives_records_it_cannot_store(tmp_path: Path) -> None:
    good = make_calls(60)
    with RecorderProcess(tmp_path / "child.mcap", chunk_size=2048) as rp:
        for method, args in interleave(good, unstorable_calls()):
            getattr(rp, method)(*args)
        rp.write_sample(object(), 0)  # not a sample at all: the child's call fails, the child goes on
        for method, args in make_calls(10, seed=9):
            getattr(rp, method)(*args)
        deadline = time.monotonic() + 10
        while rp.rejected < sum(UNSTORABLE.values()) + 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert rp.alive
    assert rp.close() is True and rp.dropped == 0
    assert rp.rejected == sum(UNSTORABLE.values()) + 1
    record(tmp_path / "direct.mcap", good + make_calls(10, seed=9), chunk_size=2048)
    assert (tmp_path / "child.mcap").read_bytes() == (tmp_path / "direct.mcap").read_bytes()
