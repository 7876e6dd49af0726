"""Damaged MCAP logs: a bad chunk is skipped, the chunks after it are read and replayed, the loss is counted.

What each chunk holds is taken from the intact file with mcap's own reader
(the summary's chunk index and ``breakup_chunk``), independent of the
project's scanner; the damage is then done to the bytes of one chunk.
"""

from __future__ import annotations

import json
from io import BytesIO
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from fuser.config import FuserConfig
from fuser.record import INPUT_TOPICS, read_log
from fuser.replay import replay
from test_fuser_record import make_calls, record

LOGS = Path(__file__).resolve().parent.parent / "logs"


def chunks_of(path: Path) -> tuple[list[tuple[int, int]], list[list[tuple[str, int, int, bytes]]]]:
    """(offset, length) of every chunk record and the messages of each, read with mcap's reader from the intact file."""
    data = path.read_bytes()
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {c.id: c.topic for c in summary.channels.values()}
    spans, contents = [], []
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        start = index.chunk_start_offset
        chunk = Chunk.read(ReadDataStream(BytesIO(data[start + 9 : start + index.chunk_length])))
        spans.append((start, index.chunk_length))
        contents.append([(topics[r.channel_id], r.log_time, r.publish_time, r.data) for r in breakup_chunk(chunk) if isinstance(r, Message)])
    return spans, contents


def damage(data: bytes, start: int, length: int, how: str) -> bytes:
    out = bytearray(data)
    if how == "data":  # flipped bytes inside the compressed data: CRC or zstd fails, the length is intact
        mid = start + length // 2
        out[mid : mid + 4] = bytes(b ^ 0xA5 for b in out[mid : mid + 4])
    elif how == "length_huge":  # the record's length points past the end of the file
        out[start + 1 : start + 9] = b"\xff" * 8
    elif how == "length_off":  # the length is wrong but stays inside the file
        out[start + 1] ^= 0x10
    elif how == "opcode":  # the record no longer says it is a chunk
        out[start] = 0x77
    return bytes(out)


def expected_without(contents: list[list[tuple]], lost: set[int]) -> list[tuple]:
    kept = [m for k, chunk in enumerate(contents) if k not in lost for m in chunk]
    return sorted(kept, key=lambda m: m[1])  # read_log's order: log time, file order on ties


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("damaged") / "small.mcap"
    record(path, make_calls(300), chunk_size=2048)
    return path


@pytest.mark.parametrize("how", ["data", "length_huge", "length_off", "opcode"])
@pytest.mark.parametrize("which", ["first", "middle", "last"])
def test_one_damaged_chunk_costs_only_its_own_messages(small_log: Path, tmp_path: Path, how: str, which: str) -> None:
    spans, contents = chunks_of(small_log)
    assert len(spans) > 20
    k = {"first": 0, "middle": len(spans) // 2, "last": len(spans) - 1}[which]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(damage(small_log.read_bytes(), *spans[k], how))

    log = read_log(bad)
    assert [tuple(m) for m in log.raw] == expected_without(contents, {k})
    assert not log.complete and log.error
    skipped = log.skipped
    assert (skipped.chunks, skipped.bytes, skipped.messages, skipped.messages_known) == (1, spans[k][1], len(contents[k]), True)
    assert skipped.resyncs == (0 if how == "data" else 1)
    assert f"1 chunk ({spans[k][1]:,} bytes, {len(contents[k])} messages" in skipped.describe()


def test_two_damaged_chunks_and_a_damaged_index(small_log: Path, tmp_path: Path) -> None:
    spans, contents = chunks_of(small_log)
    data = damage(small_log.read_bytes(), *spans[3], "data")
    data = damage(data, *spans[9], "length_huge")
    # the message index right after chunk 12: a length that no longer fits its entries
    index_at = spans[12][0] + spans[12][1]
    assert data[index_at] == 0x07
    data = data[: index_at + 1] + b"\x02" + data[index_at + 2 :]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(data)
    log = read_log(bad)
    assert [tuple(m) for m in log.raw] == expected_without(contents, {3, 9})  # an index carries no message
    assert log.skipped.chunks == 2
    assert log.skipped.messages == len(contents[3]) + len(contents[9])


def test_replay_of_a_damaged_log_goes_on_after_the_bad_chunk(tmp_path: Path) -> None:
    """The issue's case: one corrupted chunk must not cost the rest of the flight."""
    src = LOGS / "sim_hover.mcap"
    spans, contents = chunks_of(src)
    k = len(spans) // 3
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(damage(src.read_bytes(), *spans[k], "data"))
    summary = replay(bad, tmp_path / "out.mcap", FuserConfig(), progress=None)

    all_inputs = [m for chunk in contents for m in chunk if m[0] in INPUT_TOPICS]
    lost = [m for m in contents[k] if m[0] in INPUT_TOPICS]
    assert len(lost) > 10  # the damaged 64 KiB chunk holds inputs beside the estimates (one per IMU sample), /pose, /tf and /diagnostics
    assert summary.samples == len(all_inputs) - len(lost)
    assert summary.skipped is not None and summary.skipped.chunks == 1 and summary.skipped.messages == len(contents[k])
    out = read_log(tmp_path / "out.mcap")
    replayed = out.of(INPUT_TOPICS)
    assert [(m.topic, m.log_time, m.data) for m in replayed] == sorted(
        [(m[0], m[1], m[3]) for m in all_inputs if m not in lost], key=lambda m: m[1])
    # the loop ran to the end of the flight, not to the damage
    last_input_ns = max(m[1] for m in all_inputs)
    period_ns = 10_000_000
    assert max(e.t_ns for e in out.estimates()) >= last_input_ns - 2 * period_ns
    lost_end = max(m[1] for m in lost)
    assert sum(m.log_time > lost_end for m in replayed) > len(replayed) // 2


def test_a_log_with_no_inputs_is_refused_and_leaves_no_output(tmp_path: Path) -> None:
    from fuser.replay import ReplayError

    truth_only = tmp_path / "truth.mcap"
    record(truth_only, [c for c in make_calls(20) if c[0] == "write_truth"])
    out = tmp_path / "out.mcap"
    with pytest.raises(ReplayError, match="no input samples"):
        replay(truth_only, out, FuserConfig(), progress=None)
    assert list(tmp_path.iterdir()) == [truth_only]


def test_every_chunk_damaged_is_nothing_to_replay(small_log: Path, tmp_path: Path) -> None:
    from fuser.replay import ReplayError

    spans, _ = chunks_of(small_log)
    data = small_log.read_bytes()
    for span in spans:
        data = damage(data, *span, "data")
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(data)
    log = read_log(bad)
    assert log.records == 0 and log.skipped.chunks == len(spans)
    with pytest.raises(ReplayError):
        replay(bad, tmp_path / "out.mcap", FuserConfig(), progress=None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]


def test_json_of_the_surviving_records_is_intact(small_log: Path, tmp_path: Path) -> None:
    """Resynchronising never hands out a message cut from the middle of another record."""
    spans, _ = chunks_of(small_log)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(damage(small_log.read_bytes(), *spans[5], "length_off"))
    for m in read_log(bad).raw:
        json.loads(m.data)


def test_a_tlog_sample_the_output_cannot_hold_is_left_out_and_counted(tmp_path: Path) -> None:
    """A HIGHRES_IMU with time_usec = 2^63 in a .tlog: the replay's recorder refuses it and keeps everything else."""
    from pymavlink.dialects.v20 import common as mavlink2

    vehicle, spoofer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1), mavlink2.MAVLink(None, srcSystem=77, srcComponent=1)
    tlog = tmp_path / "spoofed.tlog"
    n, spoof_at = 400, 200
    with open(tlog, "wb") as f:
        for k in range(n):
            t_us = 1_700_000_000_000_000 + k * 10_000
            if k % 100 == 0:  # the autopilot's heartbeat, once a second: the fuser locks onto this vehicle
                f.write((t_us - 1).to_bytes(8, "big") + vehicle.heartbeat_encode(2, 3, 0, 0, 4).pack(vehicle))
            packet = vehicle.highres_imu_encode(5_000_000 + k * 10_000, 0, 0, -9.81, 0.01, 0, 0, 0.21, 0, 0.43, 1013, 0, 0, 20, 0x1FF)
            f.write(t_us.to_bytes(8, "big") + packet.pack(vehicle))
            if k == spoof_at:
                bad = spoofer.highres_imu_encode(2**63, 0, 0, -9.81, 0.01, 0, 0, 0.21, 0, 0.43, 1013, 0, 0, 20, 0x1FF)
                f.write((t_us + 1).to_bytes(8, "big") + bad.pack(spoofer))
    summary = replay(tlog, tmp_path / "out.mcap", FuserConfig(), progress=None)
    refused = summary.not_recorded.get("time_out_of_range", 0)
    assert summary.samples - n == refused in (0, 1)  # refused here, or already by the decoder's own range check
    with open(tmp_path / "out.mcap", "rb") as f:  # complete: mcap's reader needs the footer
        imu = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages() if c.topic == "/input/imu"]
    assert [d["t_ns"] for d in imu] == [(5_000_000 + k * 10_000) * 1000 for k in range(n)]
