"""Offline replay: a recorded log through the same loop on a virtual clock, as fast as possible.

The clock is the recorded receive time of each sample, so ticks fall exactly
where they fell live, and two replays of one log write byte-identical
files. The output MCAP holds the inputs again (so it can itself be
replayed), the estimates, the status once a second (as ``sim`` records it), and the
log's truth if it had any. Inputs and
truth from an MCAP log are copied as they are stored (JSON bytes), not
decoded and encoded again. Every record goes into the output in log-time order,
the copied truth between the estimates and inputs of its time. An MCAP log is read
as a stream (:class:`~fuser.record.LogStream`), not whole, so a replay's memory
does not grow with the log's length.

A damaged MCAP replays every chunk that can be read (``ReplaySummary.skipped``
says what could not). A file that is not a log raises
:class:`~fuser.errors.NotALogError`, a log with nothing to replay
:class:`ReplayError`; in both cases, and whenever replay fails, no output file
is left behind (it is written under a temporary name and renamed at the end).
"""

from __future__ import annotations

import glob
import math
import os
import sys
import tempfile
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from dataclasses import replace as with_fields
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, TextIO

from drivers.samples import Sample
from fuser.codec import Estimate, decode_sample, loads
from fuser.config import FuserConfig
from fuser.errors import FuserError, NotALogError, check_log_file
from fuser.importers import import_log, is_importable
from fuser.inputs import InputReport, TlogInputs
from fuser.mcap_scan import RawMessage, Skipped
from fuser.progress import progress_bar
from fuser.record import INPUT_TOPICS, LogStream, McapRecorder, RecordWriteError

if TYPE_CHECKING:
    from fuser.pipeline import Pipeline

__all__ = ["ReplayError", "ReplaySummary", "leftovers", "replay"]

MAX_CATCH_UP_TICKS = 1000
"""A gap in a log longer than this many ticks is skipped (counted), not filled tick by tick."""


class ReplayError(FuserError):
    """The log holds nothing that could be replayed."""


@dataclass(frozen=True)
class ReplaySummary:
    samples: int
    estimates: int
    seconds: float
    counters: dict[str, int]
    incomplete: str | None = None
    """Why an MCAP log was not read to its footer (cut short, damaged), or None."""
    skipped: Skipped | None = None
    """What a damaged MCAP log lost (chunks, bytes, messages), or None if nothing was skipped."""
    not_recorded: dict[str, int] = field(default_factory=dict)
    """Records the output could not hold, by reason (``McapRecorder.rejected``: a time outside uint64, NaN)."""
    inputs: InputReport | None = None
    """A .tlog's account: decodable IMU messages, those the loop took, everything refused by reason."""
    imported: dict[str, int] | None = None
    """For a log replayed through ``import`` (DataFlash, ULog, BROAD): what the import left out, by reason: the records
    it skipped and the samples its decoder refused (:attr:`fuser.importers.ImportSummary.skipped` and ``refused``, as
    ``import`` prints them); None for an MCAP or a .tlog."""

    compile_seconds: float = 0.0
    """Of ``seconds``, those numba spent compiling the filter (the first run after installing, :mod:`fuser.compiling`)."""

    @property
    def samples_per_s(self) -> float:
        """The replay's rate, without the compiling."""
        fusing = self.seconds - self.compile_seconds
        return self.samples / fusing if fusing > 0 else float("inf")


class _LogReader:
    """An MCAP log's inputs and its ``/truth/pose``, read once in log-time order (:meth:`LogStream.messages`) for
    two readers that go at different paces: the replay takes the inputs one by one, :class:`_CopiedInOrder` the
    truth up to a time. What one reader reads past is kept for the other; both keep close to the same time, so
    little is kept."""

    def __init__(self, messages: Iterator[RawMessage]) -> None:
        self._messages = messages
        self._inputs: deque[RawMessage] = deque()
        self._truth: deque[RawMessage] = deque()
        self._read_to: int | None = None
        """Log time of the last message read; None before the first."""
        self._ended = False

    def _read_one(self) -> bool:
        """Read the next message into its queue; False at the end of the log."""
        m = next(self._messages, None)
        if m is None:
            self._ended = True
            return False
        (self._truth if m.topic == "/truth/pose" else self._inputs).append(m)
        self._read_to = m.log_time
        return True

    def inputs(self) -> Iterator[RawMessage]:
        """The input messages in log-time order."""
        while self._inputs or self._read_one():
            if self._inputs:
                yield self._inputs.popleft()

    def truth_until(self, t_ns: int | float) -> Iterator[RawMessage]:
        """The truth messages not taken yet whose log time is at or before ``t_ns``, in log-time order."""
        while not self._ended and (self._read_to is None or self._read_to <= t_ns):
            self._read_one()
        truth = self._truth
        while truth and truth[0].log_time <= t_ns:
            yield truth.popleft()


class _CopiedInOrder:
    """Records copied from the log (its ``/truth/pose``), written into the output in log-time order with the rest.

    :meth:`until` writes every one not written yet whose log time is at or before ``t_ns``. Called before each
    record the replay writes, with that record's log time, it puts each copied record where it belongs in time,
    so the whole file is in log-time order (as the MCAP specification recommends, and as Foxglove and readers that
    stream it expect) without holding anything back: the messages are read from the log as they are needed.
    """

    def __init__(self, recorder: McapRecorder, log: _LogReader | None) -> None:
        self._recorder = recorder
        self._log = log

    def until(self, t_ns: int | float) -> None:
        if self._log is not None:
            for m in self._log.truth_until(t_ns):
                self._recorder.write_message(*m)

    def rest(self) -> None:
        """Write what is left (the records after the last estimate)."""
        self.until(math.inf)


class _Status:
    """The status on ``/status`` once a second of the log's receive time, as ``sim`` records it: the pipeline's
    (:meth:`Pipeline.status`) and the recorder's health, after the samples received at one instant and before the
    ticks of the next. A replay of a ``sim --speed 0`` recording writes its status records again, the same."""

    def __init__(self, recorder: McapRecorder, pipeline: Pipeline, copied: _CopiedInOrder) -> None:
        from fuser.pipeline import STATUS_PERIOD_NS  # noqa: PLC0415 - as Pipeline: the model loads once the log is known to be one

        self._period_ns = STATUS_PERIOD_NS
        self._recorder = recorder
        self._pipeline = pipeline
        self._copied = copied
        self._next_ns: int | None = None
        self._last_ns: int | None = None

    def before(self, receive_ns: int) -> None:
        """A sample received at ``receive_ns`` is next (before the ticks due by then run)."""
        last = self._last_ns
        if last is None:
            self._next_ns = receive_ns + self._period_ns
        elif receive_ns > last:
            self._at(last)
        self._last_ns = receive_ns

    def end(self) -> None:
        """After the last sample, before the ticks that cover what is still buffered."""
        if self._last_ns is not None:
            self._at(self._last_ns)

    def _at(self, t_ns: int) -> None:
        if t_ns < self._next_ns:  # type: ignore[operator]
            return
        self._next_ns += self._period_ns * ((t_ns - self._next_ns) // self._period_ns + 1)  # type: ignore[operator]  # once, after a gap too
        self._copied.until(t_ns)
        self._recorder.write_status(t_ns, {**self._pipeline.status(), "recorder": self._recorder.health()})


def _copied_inputs(messages: Iterable[RawMessage], pipeline: Pipeline, recorder: McapRecorder, copied: _CopiedInOrder,
                   status: _Status) -> Iterator[tuple[Sample, int]]:
    """An MCAP log's inputs, each written unchanged to ``recorder`` where an input sink of the pipeline would write it
    (after the status due, the ticks due before it and the copied records up to its time)."""
    for m in messages:
        sample, receive_ns = decode_sample(m.topic, loads(m.data))
        status.before(receive_ns)
        pipeline.advance(receive_ns)  # as in Pipeline.feed: the ticks due before the sample are recorded before it
        copied.until(receive_ns)
        recorder.write_message(m.topic, receive_ns, sample.t_ns, m.data)
        yield sample, receive_ns


def _timed(inputs: Iterable[tuple[Sample, int]], status: _Status) -> Iterator[tuple[Sample, int]]:
    """``inputs``, each after the status due before it (Pipeline.feed then runs the ticks due and takes it)."""
    for sample, receive_ns in inputs:
        status.before(receive_ns)
        yield sample, receive_ns


def _open_mcap(log: Path) -> LogStream:
    """The log, read once to count what it holds; ReplayError if it has no input message."""
    stream = LogStream(log)
    overview = stream.overview
    if not overview.count(INPUT_TOPICS):
        what = (overview.describe() if overview.records else f"no record could be read ({overview.error})" if overview.error
                else "it holds no messages")
        raise ReplayError(f"nothing to replay in {log}: no input samples ({what})")
    return stream


TLOG_PROBE_BYTES = 64 * 1024


def _check_tlog(log: Path) -> None:
    """Refuse a file with no MAVLink start byte (0xFE v1, 0xFD v2) in its first 64 KiB: empty, text, another format.

    A .tlog is records of an 8-byte receive time and a MAVLink packet; what
    else it holds (garbage, bad CRCs) the decoder counts, so only a file that
    cannot hold a single packet is refused here.
    """
    with open(log, "rb") as f:
        head = f.read(TLOG_PROBE_BYTES)
    if b"\xfd" not in head and b"\xfe" not in head:
        raise NotALogError(f"{log} is not a MAVLink telemetry log ({'it is empty' if not head else 'no MAVLink packet in it'})")


def replay(log: str | Path, out: str | Path, config: FuserConfig, progress: TextIO | None = sys.stderr,
           notice: Callable[[], None] | None = None) -> ReplaySummary:
    """Fuse every input of ``log`` (MCAP, .tlog, or a log ``import`` reads) and record the result to ``out``.

    ``progress``: where to draw a progress bar (only if it is a terminal). ``notice``: called once, from a timer
    thread, if the filter's kernels have been compiling for :data:`fuser.compiling.NOTICE_AFTER_S` (the first run
    after installing); the seconds they took are the summary's ``compile_seconds``.
    """
    log, out = Path(log), Path(out)
    check_log_file(log)
    from fuser.compiling import compile_watch  # noqa: PLC0415 - numba loads only once the log is known to be there

    with compile_watch(notice) as compiling:
        if is_importable(log):
            summary = _replay_imported(log, out, config, progress)
        else:
            summary = _replay(log, out, config, progress, log.name)
    return with_fields(summary, compile_seconds=compiling.seconds)


def _import_prefix(log: Path) -> str:
    """The name a temporary import of ``log`` begins with (a hidden folder beside the output)."""
    return f".{log.stem}.import."


def _partial_prefix(out: Path) -> str:
    """The name the output ``out`` has while it is written (then the writer's process id and ``.partial``)."""
    return f".{out.name}."


def leftovers(log: str | Path, out: str | Path) -> list[Path]:
    """What a replay of ``log`` into ``out`` killed from outside (SIGKILL, out of memory) leaves beside ``out``:
    its partial output and its temporary import. A replay that ends, even by an error, removes its own."""
    log, out = Path(log), Path(out)
    return sorted([*out.parent.glob(f"{glob.escape(_partial_prefix(out))}*.partial"),
                   *out.parent.glob(f"{glob.escape(_import_prefix(log))}*")])


def _replay_imported(log: Path, out: Path, config: FuserConfig, progress: TextIO | None) -> ReplaySummary:
    """A DataFlash log, PX4 ULog or BROAD trial: imported (:func:`fuser.importers.import_log`, into a temporary MCAP
    beside ``out``) and that replayed, with the reference field the import found unless ``config`` sets one: the
    same estimates as ``import LOG -o X.mcap`` then ``replay X.mcap --config X.toml``, in one step, so that a batch
    of such logs each gets its own field. What the import left out (skipped, or refused by its decoder) is in the
    summary's ``imported``."""
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=_import_prefix(log), dir=out.parent) as folder:
        imported = import_log(log, Path(folder) / f"{log.stem}.mcap", progress=progress)
        if config.mag.field_ned_gauss is None:
            config = config.replace(mag={"field_ned_gauss": imported.mag_field_ned_gauss})
        summary = _replay(imported.path, out, config, progress, log.name)
    return with_fields(summary, seconds=time.monotonic() - start, imported=imported.skipped | imported.refused)


def _replay(log: Path, out: Path, config: FuserConfig, progress: TextIO | None, source_name: str) -> ReplaySummary:
    """:func:`replay` of an MCAP or a .tlog; ``source_name`` goes into the output's metadata (``source_log``)."""
    is_tlog = log.suffix.lower() == ".tlog"  # any case: FAT cards and some tools name files in capitals
    if is_tlog:
        _check_tlog(log)
    stream = None if is_tlog else _open_mcap(log)
    overview = None if stream is None else stream.overview
    log_reader = None if stream is None else _LogReader(stream.messages((*INPUT_TOPICS, "/truth/pose")))
    from fuser.pipeline import Pipeline  # noqa: PLC0415 - the model's kernels load only once the log is known to be one

    partial = out.with_name(f"{_partial_prefix(out)}{os.getpid()}.partial")
    start = time.monotonic()
    samples = 0
    provenance = {} if overview is None else overview.metadata.get("bingham_fuser", {})  # reference, source, attribution
    try:
        with McapRecorder(partial, metadata={**provenance, "source_log": source_name}, stop_on_write_error=True) as recorder:
            copied = _CopiedInOrder(recorder, log_reader)

            def write_estimate(est: Estimate) -> None:
                copied.until(est.t_ns)
                recorder.write_estimate(est)

            pipeline = Pipeline(config, [], [write_estimate], MAX_CATCH_UP_TICKS)
            status = _Status(recorder, pipeline, copied)
            tlog = TlogInputs(log, config.link) if log_reader is None else None
            if tlog is not None:
                pipeline.inputs.append(recorder.write_sample)
                feed = tlog.feeder(pipeline)
                inputs: Iterable[tuple[Sample, int]] = _timed(progress_bar(tlog, None, "replay", " samples", progress), status)
            else:
                assert log_reader is not None and overview is not None  # an MCAP log
                feed = pipeline.feed
                messages = progress_bar(log_reader.inputs(), overview.count(INPUT_TOPICS), "replay", " samples", progress)
                inputs = _copied_inputs(messages, pipeline, recorder, copied, status)
            for sample, receive_ns in inputs:
                feed(sample, receive_ns)
                samples += 1
            status.end()
            pipeline.finish()
            copied.rest()
        if samples == 0:
            refused = "" if tlog is None else "; not used: " + (", ".join(f"{k}={v:,}" for k, v in tlog.report().refused.items()) or "nothing")
            raise ReplayError(f"nothing to replay in {log}: no IMU, magnetometer, attitude or GNSS message could be decoded{refused}")
        os.replace(partial, out)
    except RecordWriteError as e:  # a full disk: stop at once, by the output's own name
        partial.unlink(missing_ok=True)
        raise ReplayError(f"cannot write {out}: {e.reason}; nothing was kept") from e
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    counters = dict(pipeline.loop.counters) | dict(pipeline.loop.model.counters)
    incomplete = None if overview is None or overview.complete else overview.error
    skipped = overview.skipped if overview is not None and overview.skipped else None
    return ReplaySummary(samples, pipeline.estimates, time.monotonic() - start, counters, incomplete, skipped, dict(recorder.rejected),
                         None if tlog is None else tlog.report())
