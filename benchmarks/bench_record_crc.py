"""What the MCAP data-section CRC costs the recorder: records/s with and without, same run.

    python benchmarks/bench_record_crc.py

``fuser/record.py`` writes with ``enable_data_crcs=True`` (mcap's Writer defaults to False, which
leaves the DataEnd CRC 0, so a flipped byte in a message index goes undetected). The CRC is
zlib.crc32 over every byte of the data section as it is written. Two paths, each best of five:
``McapRecorder.write_sample`` (JSON encoding + zstd chunks: what a live recording pays per input)
and ``Writer.add_message`` of pre-encoded 200-byte messages (the writer alone, where the CRC's share
is largest). Records are IMU samples at 400 Hz.
"""

from __future__ import annotations

import functools
import io
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import mcap.writer  # noqa: E402

import fuser.record as record  # noqa: E402
from drivers.samples import ImuSample, SourceId  # noqa: E402

N = 50_000
SAMPLES = [
    ImuSample(5_000_000_000 + 2_500_000 * i, (0.01 * (i % 100), -0.02, 0.3), (0.1, -0.2, -9.8), (0.21, 0.01, 0.43), SourceId("mavlink", 1, 1, 0))
    for i in range(N)
]


def best_rate(run: Callable[[], None], repeats: int = 5) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t)
    return N / best


def recorder_run(crc: bool) -> Callable[[], None]:
    def run() -> None:
        original = record.Writer
        record.Writer = functools.partial(_writer, crc)  # type: ignore[misc]
        try:
            with tempfile.TemporaryDirectory() as d, record.McapRecorder(os.path.join(d, "r.mcap")) as rec:
                for s in SAMPLES:
                    rec.write_sample(s, s.t_ns + 1_000_000)
        finally:
            record.Writer = original  # type: ignore[misc]

    return run


def _writer(crc: bool, *args, **kwargs) -> mcap.writer.Writer:
    return mcap.writer.Writer(*args, **{**kwargs, "enable_data_crcs": crc})


def writer_run(crc: bool) -> Callable[[], None]:
    payload = b"x" * 200

    def run() -> None:
        w = mcap.writer.Writer(io.BytesIO(), chunk_size=64 * 1024, enable_data_crcs=crc)
        w.start()
        sid = w.register_schema("s", "jsonschema", b"{}")
        cid = w.register_channel("/c", "json", sid)
        for i in range(N):
            w.add_message(cid, i, payload, i, i)
        w.finish()

    return run


def main() -> None:
    print(f"{N:,} records per run, best of five; Python {sys.version.split()[0]}\n")
    print("| path | without data CRC (records/s) | with data CRC (records/s) | cost |")
    print("| --- | --- | --- | --- |")
    for name, make in (("McapRecorder.write_sample (JSON, zstd)", recorder_run), ("Writer.add_message, 200-byte messages", writer_run)):
        without, with_crc = best_rate(make(False)), best_rate(make(True))
        print(f"| {name} | {without:,.0f} | {with_crc:,.0f} | {100 * (without / with_crc - 1):+.1f}% time |")


if __name__ == "__main__":
    main()
