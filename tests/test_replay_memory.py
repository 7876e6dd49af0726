"""Replay and its score read logs as streams: the same messages in the same order as ``read_log``, the same score
text as the whole-log computation, in memory that does not grow with the log (issue: 2.14 GB for a 10-minute log)."""

from __future__ import annotations

import json
import random
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drivers.samples import ImuSample, SourceId
from fuser import report
from fuser.record import LogStream, McapRecorder, read_log

LOGS = Path(__file__).resolve().parent.parent / "logs"
SIM_LOGS = sorted(LOGS.glob("sim_*.mcap"))


def _same_as_read_log(path: Path) -> None:
    contents = read_log(path)
    stream = LogStream(path)
    assert list(stream.messages()) == contents.raw
    assert list(stream.messages(["/truth/pose", "/input/imu"])) == contents.of(["/truth/pose", "/input/imu"])
    overview = stream.overview
    assert (overview.complete, overview.error, overview.metadata, overview.skipped) == \
        (contents.complete, contents.error, contents.metadata, contents.skipped)
    assert overview.describe() == contents.describe()


@pytest.mark.parametrize("log", SIM_LOGS, ids=lambda p: p.stem)
def test_stream_is_read_log_in_order(log: Path) -> None:
    _same_as_read_log(log)


def _unordered_log(path: Path, n: int = 3000) -> None:
    """Small chunks whose messages run back in time, and equal log times across chunks: the merge's hard cases."""
    rng = random.Random(7)
    with McapRecorder(path, chunk_size=2048, metadata={"source": "test"}) as rec:
        for i in range(n):
            t = rng.randrange(0, n // 3) * 1_000_000 if i % 5 else i * 1_000_000
            rec.write_message("/input/imu" if i % 2 else "/truth/pose", t, t + 1, json.dumps({"i": i}).encode())


def test_stream_merges_a_log_out_of_order(tmp_path: Path) -> None:
    _unordered_log(tmp_path / "unordered.mcap")
    _same_as_read_log(tmp_path / "unordered.mcap")


def test_stream_merges_a_log_in_order_but_for_a_few_steps_back(tmp_path: Path) -> None:
    """Chunks in log-time order are let out as they are (fuser/record.py, :func:`LogStream.messages`), the others
    through the merge: a log in order but for a message a little back in time now and then (in its own chunk or
    the next one's span), and equal log times across chunk boundaries, read as read_log reads it."""
    path = tmp_path / "steps.mcap"
    with McapRecorder(path, chunk_size=2048, metadata={"source": "test"}) as rec:
        for i in range(3000):
            t = (i // 3) * 1_000_000 - (40_000_000 if i % 397 == 0 else 0)
            rec.write_message("/input/imu" if i % 2 else "/truth/pose", t, t + 1, json.dumps({"i": i}).encode())
    _same_as_read_log(path)


def test_stream_reads_a_damaged_or_cut_log_as_read_log(tmp_path: Path) -> None:
    _unordered_log(tmp_path / "whole.mcap")
    data = bytearray((tmp_path / "whole.mcap").read_bytes())
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) * 2 // 3])
    data[len(data) // 3] ^= 0xFF  # inside a chunk: its CRC fails
    (tmp_path / "damaged.mcap").write_bytes(data)
    for name in ("cut", "damaged"):
        assert not read_log(tmp_path / f"{name}.mcap").complete
        _same_as_read_log(tmp_path / f"{name}.mcap")


def _whole_log_score(path: Path) -> list[str]:
    """The score as it was computed before streaming: every estimate in memory (``errors_of_log``)."""
    contents = read_log(path)
    result = report.errors_of_log(path, contents)
    if result is None:
        return [f"{path}: {report._unscored(path, contents)}"]
    err, ref = result[1], report.reference_of(contents)
    if err.t_ns.size == 0:
        return [f"{path}: no estimate within the time span of the {ref.name} to score against"]
    circular = report._circular(contents, ref)
    since_s = report._window(err, report.CONVERGENCE_S)
    return report._score_lines(ref, err.rms(since_s), since_s, err.coverage(since_s)) + ([circular] if circular else [])


@pytest.mark.parametrize("block", [100_000, 700], ids=["one_block", "many_blocks"])
@pytest.mark.parametrize("log", SIM_LOGS, ids=lambda p: p.stem)
def test_streamed_score_is_the_whole_log_score(log: Path, block: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(report, "ESTIMATES_PER_BLOCK", block)
    assert report.score_log(log) == _whole_log_score(log)


def test_unscored_logs_say_why_as_before(tmp_path: Path) -> None:
    imported = LOGS / "px4_sample_cut.mcap"  # inputs and truth, no estimate
    assert report.score_log(imported) == _whole_log_score(imported)
    shutil.copy(SIM_LOGS[0], tmp_path / "copy.mcap")
    assert report.score_log(tmp_path / "copy.mcap") == _whole_log_score(tmp_path / "copy.mcap")


ESTIMATE = {"M": [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
            "Z": [-900.0, -900.0, -400.0, 0.0], "q_wxyz": [0.999, 0.01, 0.02, 0.03], "uncertainty_deg": 2.5,
            "euler_deg": [1.0, 2.0, 3.0], "counters": {"samples": 1, "ticks": 1}, "predicted": False}


def _long_fused_log(path: Path, seconds: int) -> None:
    """A fused log's worth of messages, quickly: an IMU input at 400 Hz, an estimate at 200 Hz, truth at 10 Hz."""
    source = SourceId("sim", 1, 1, 0)
    with McapRecorder(path) as rec:
        for k in range(seconds * 400):
            t = 1_000_000_000 + k * 2_500_000
            rec.write_sample(ImuSample(t, (0.0, 0.0, 0.01), (0.0, 0.0, -9.81), None, source), t)
            if k % 2 == 0:
                est = {**ESTIMATE, "t_ns": t, "sensor_t_ns": t}
                rec.write_message("/estimate", t, t, json.dumps(est).encode())
            if k % 40 == 0:
                rec.write_truth(t, (1.0, 0.0, 0.0, 0.0))


CHILD = textwrap.dedent("""
    import sys
    from fuser.record import LogStream
    from fuser.report import score_log
    def status_mb(field):  # VmHWM, not ru_maxrss: that one keeps the peak of the parent it was forked from
        line = next(line for line in open("/proc/self/status") if line.startswith(field + ":"))
        return int(line.split()[1]) / 1024
    start = status_mb("VmRSS")
    for _ in LogStream(sys.argv[1]).messages():  # what replay reads
        pass
    print(score_log(sys.argv[1])[1])
    print(status_mb("VmHWM") - start)
""")


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the peak RSS from /proc")
def test_reading_and_scoring_a_long_log_takes_bounded_memory(tmp_path: Path) -> None:
    """Ten minutes of a fused log (240,000 inputs, 120,000 estimates): reading all its messages in order, as replay
    does, and scoring it, grow the process by less than 100 MB (48 MB measured). The whole-log reading grew it by 586 MB;
    the score's blocks holding each estimate's Bingham as the JSON's Python lists, 146 MB (150 was the bound then)."""
    path = tmp_path / "long.mcap"
    _long_fused_log(path, 600)
    out = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parent.parent)
    score, growth_mb = out.stdout.splitlines()
    assert score.startswith("  total ")
    assert float(growth_mb) < 100, f"peak RSS grew by {float(growth_mb):.0f} MB reading and scoring the log"
