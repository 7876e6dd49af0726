"""MCAP recording of inputs, estimates, truth and status, and recovery of killed recordings.

Every message is JSON (``fuser.codec``) on a channel with a ``jsonschema``
schema; the attitude is also written as Foxglove's ``foxglove.PoseInFrame`` so
Foxglove shows it in 3D. Nothing reads the wall clock: the same calls give the
same bytes. The file is flushed after every chunk, so a recorder killed at any
moment leaves every complete chunk readable (see :func:`read_log`); smaller
chunks lose less. :class:`RecorderProcess` runs the recorder in a child
process so that the fusion loop never waits for, nor dies with, the disk.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import queue
import signal
import struct
from dataclasses import dataclass, field
from functools import cached_property
from io import BytesIO
from operator import itemgetter
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Iterable, NamedTuple

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, McapRecord, Message, Metadata
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import CompressionType, Writer

from drivers.samples import Quat, Sample

from .codec import Estimate, decode_sample, dumps, loads, sample_channel, sample_json

__all__ = ["CHANNELS", "LogContents", "McapRecorder", "RawMessage", "RecorderProcess", "pose_in_frame", "read_log"]

log = logging.getLogger(__name__)

FRAME_ID = "ned"
INPUT_TOPICS = ("/input/imu", "/input/mag", "/input/attitude", "/input/gnss")

_NUM = {"type": "number"}
_INT = {"type": "integer"}


def _vec(names: str, title: str) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": {n: _NUM for n in names}, "required": list(names)}


def _array(n: int, description: str) -> dict[str, Any]:
    return {"type": "array", "items": _NUM, "minItems": n, "maxItems": n, "description": description}


def _obj(title: str, description: str, properties: dict[str, Any], required: bool = True) -> dict[str, Any]:
    out = {"title": title, "description": description, "type": "object", "properties": properties}
    if required:
        out["required"] = list(properties)
    return out


POSE_IN_FRAME = _obj(
    "foxglove.PoseInFrame",
    "A timestamped pose for an object or reference frame in 3D space",
    {
        "timestamp": _obj(
            "time",
            "Timestamp of pose",
            {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
        ),
        "frame_id": {"type": "string", "description": "Frame of reference for pose position and orientation"},
        "pose": _obj(
            "foxglove.Pose",
            "Pose in 3D space",
            {
                "position": _vec("xyz", "foxglove.Vector3"),
                "orientation": _vec("xyzw", "foxglove.Quaternion"),
            },
        ),
    },
)

_SOURCE = _obj(
    "source",
    "transport (mavlink, dronecan, sim), system id (CAN node id), component id, sensor instance",
    {"transport": {"type": "string"}, "system": _INT, "component": _INT, "instance": _INT},
)


def _input_schema(title: str, description: str, vectors: dict[str, dict[str, Any]]) -> dict[str, Any]:
    times = {
        "t_ns": {"type": "integer", "description": "sender's message time, ns"},
        "receive_ns": {"type": "integer", "description": "time the fuser received it, ns (the MCAP log time)"},
        "source": _SOURCE,
    }
    return _obj(title, description, {**times, **vectors})


ESTIMATE = _obj(
    "bingham_fuser.Estimate",
    "Fused attitude: Bingham posterior at one loop tick",
    {
        "t_ns": {"type": "integer", "description": "tick time, ns"},
        "q_wxyz": _array(4, "unit quaternion w,x,y,z rotating body FRD into world NED"),
        "M": {"type": "array", "items": _array(4, "row"), "minItems": 4, "maxItems": 4, "description": "Bingham M, 4x4 row-major, columns are the axes"},
        "Z": _array(4, "Bingham concentrations, one per column of M (<= 0)"),
        "uncertainty_deg": {"type": "number", "description": "RMS angular deviation, degrees"},
        "euler_deg": _array(3, "roll, pitch, yaw (ZYX), degrees"),
        "counters": {"type": "object", "additionalProperties": _INT},
    },
)

# topic -> schema; channel ids follow this order (registration order).
CHANNELS: dict[str, dict[str, Any]] = {
    "/input/imu": _input_schema(
        "bingham_fuser.ImuSample",
        "IMU sample, body FRD",
        {
            "gyro_rad_s": _array(3, "angular rate, rad/s"),
            "accel_m_s2": _array(3, "specific force, m/s^2"),
            "mag_gauss": {"anyOf": [_array(3, "magnetic field, gauss"), {"type": "null"}]},
        },
    ),
    "/input/mag": _input_schema("bingham_fuser.MagSample", "magnetometer sample, body FRD", {"mag_gauss": _array(3, "gauss")}),
    "/input/attitude": _input_schema(
        "bingham_fuser.AttitudeSample", "attitude from an autopilot", {"q_wxyz": _array(4, "w,x,y,z body FRD to NED")}
    ),
    "/input/gnss": _input_schema(
        "bingham_fuser.GnssSample",
        "GNSS velocity (and position) solution, world NED",
        {
            "fix_type": {**_INT, "description": "MAVLink GPS_FIX_TYPE: 0 no GPS, 1 no fix, 2 2-D, 3 3-D, 4 DGPS, 5/6 RTK"},
            "vel_ned_m_s": {"anyOf": [_array(3, "velocity north, east, down, m/s"), {"type": "null"}]},
            "vertical_velocity": {"type": "boolean", "description": "whether the down velocity was measured"},
            "speed_accuracy_m_s": {"type": ["number", "null"], "description": "one-sigma speed accuracy, m/s"},
            "lat_deg": {"type": ["number", "null"], "description": "WGS84 latitude, degrees"},
            "lon_deg": {"type": ["number", "null"], "description": "WGS84 longitude, degrees"},
            "alt_m": {"type": ["number", "null"], "description": "altitude above mean sea level, m"},
            "filtered": {"type": "boolean", "description": "an autopilot's fused solution, not a receiver's fix"},
        },
    ),
    "/estimate": ESTIMATE,
    "/pose": POSE_IN_FRAME,
    "/truth/pose": POSE_IN_FRAME,
    "/status": {"title": "bingham_fuser.Status", "description": "health and counters", "type": "object"},
}


def pose_in_frame(t_ns: int, q_wxyz: Quat) -> dict[str, Any]:
    """A ``foxglove.PoseInFrame`` dict (orientation in x, y, z, w order) at the origin of NED."""
    w, x, y, z = q_wxyz
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": FRAME_ID,
        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": x, "y": y, "z": z, "w": w}},
    }


class _ChunkOutput:
    """The file as the mcap ``Writer`` sees it; ``wrote`` turns True when it hands over data.

    The writer writes only when a chunk is complete, so the recorder flushes
    the file (and counts what is safe on disk) only then, not per message.
    """

    def __init__(self, file: BinaryIO) -> None:
        self.file = file
        self.wrote = False

    def write(self, data: bytes) -> int:
        self.wrote = True
        return self.file.write(data)

    def tell(self) -> int:
        return self.file.tell()

    def flush(self) -> None:
        self.file.flush()


class McapRecorder:
    """Write inputs, estimates, truth and status to an MCAP file (zstd chunks, JSON messages).

    ``records_on_disk`` counts the messages already in complete chunks written
    to the file, i.e. what survives if the process is killed now.
    """

    def __init__(self, path: str | Path, chunk_size: int = 64 * 1024, metadata: dict[str, str] | None = None) -> None:
        self._file = open(path, "wb")
        self._output = _ChunkOutput(self._file)
        self._writer = Writer(self._output, chunk_size=chunk_size, compression=CompressionType.ZSTD)  # type: ignore[arg-type]
        self._writer.start(profile="", library="bingham-fuser")
        if metadata:
            self._writer.add_metadata("bingham_fuser", dict(sorted(metadata.items())))
        schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        for topic, schema in CHANNELS.items():
            name = schema["title"]
            if name not in schema_ids:
                schema_ids[name] = self._writer.register_schema(name, "jsonschema", dumps(schema))
            self._channels[topic] = self._writer.register_channel(topic, "json", schema_ids[name])
            self._sequence[topic] = 0
        self._count = 0
        self._file.flush()
        self._output.wrote = False
        self.records_on_disk = 0
        self.closed = False

    def write_message(self, topic: str, log_time: int, publish_time: int, data: bytes) -> None:
        """One message already encoded as JSON (e.g. copied unchanged from another log)."""
        seq = self._sequence[topic] = self._sequence[topic] + 1
        self._writer.add_message(self._channels[topic], log_time, data, publish_time, seq)
        self._count += 1
        if self._output.wrote:  # the chunk just closed goes to the OS at once
            self._output.wrote = False
            self._file.flush()
            self.records_on_disk = self._count

    def write_sample(self, sample: Sample, receive_ns: int) -> None:
        """An input sample; log time = receive time, publish time = the sender's time."""
        self.write_message(sample_channel(sample), receive_ns, sample.t_ns, sample_json(sample, receive_ns))

    def write_estimate(self, est: Estimate) -> None:
        """An estimate on ``/estimate`` (full) and ``/pose`` (Foxglove), at its tick time."""
        self.write_message("/estimate", est.t_ns, est.t_ns, est.to_json())
        self.write_message("/pose", est.t_ns, est.t_ns, dumps(pose_in_frame(est.t_ns, est.q_wxyz)))

    def write_truth(self, t_ns: int, q_wxyz: Quat) -> None:
        """The true attitude (simulator, imported logs) on ``/truth/pose``."""
        self.write_message("/truth/pose", t_ns, t_ns, dumps(pose_in_frame(t_ns, q_wxyz)))

    def write_status(self, t_ns: int, status: dict[str, Any]) -> None:
        """A health/counters dict on ``/status``."""
        self.write_message("/status", t_ns, t_ns, dumps(status))

    def close(self) -> None:
        """Write the last chunk, the summary and the footer; idempotent."""
        if self.closed:
            return
        self.closed = True
        self._writer.finish()
        self._file.close()
        self.records_on_disk = self._count

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


def _record_child(
    path: str, chunk_size: int, metadata: dict[str, str] | None, q: mp.Queue, on_disk: Any, parent: int
) -> None:
    """Child process: apply queued ``(method, args)`` calls until ``None`` or the parent is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the parent, which closes us cleanly
    with McapRecorder(path, chunk_size, metadata) as rec:
        while True:
            try:
                item = q.get(timeout=0.5)
            except queue.Empty:
                if os.getppid() != parent:
                    break
                continue
            if item is None:
                break
            method, args = item
            getattr(rec, method)(*args)
            on_disk.value = rec.records_on_disk
    on_disk.value = rec.records_on_disk


class RecorderProcess:
    """The :class:`McapRecorder` API, forwarded to a recorder in a child process.

    Writes never block nor raise: when the queue is full or the child is dead
    the call is counted in ``dropped``. ``records_on_disk`` is how many
    records the child has in complete chunks on disk.
    """

    def __init__(
        self,
        path: str | Path,
        chunk_size: int = 64 * 1024,
        metadata: dict[str, str] | None = None,
        queue_size: int = 10_000,
    ) -> None:
        ctx = mp.get_context("spawn")  # the parent runs zenoh threads: never fork it
        self._queue: mp.Queue = ctx.Queue(queue_size)
        self._on_disk = ctx.RawValue("q", 0)
        self._proc = ctx.Process(
            target=_record_child,
            args=(str(path), chunk_size, metadata, self._queue, self._on_disk, os.getpid()),
            name="bingham-fuser-recorder",
            daemon=True,
        )
        self._proc.start()
        self.submitted = 0
        self.dropped = 0
        self._closed = False

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    @property
    def alive(self) -> bool:
        return self._proc.is_alive()

    @property
    def records_on_disk(self) -> int:
        return int(self._on_disk.value)

    def _put(self, method: str, *args: Any) -> None:
        if self._closed or not self._proc.is_alive():
            self.dropped += 1
            return
        try:
            self._queue.put_nowait((method, args))
            self.submitted += 1
        except queue.Full:
            self.dropped += 1

    def write_sample(self, sample: Sample, receive_ns: int) -> None:
        self._put("write_sample", sample, receive_ns)

    def write_estimate(self, est: Estimate) -> None:
        self._put("write_estimate", est)

    def write_truth(self, t_ns: int, q_wxyz: Quat) -> None:
        self._put("write_truth", t_ns, tuple(q_wxyz))

    def write_status(self, t_ns: int, status: dict[str, Any]) -> None:
        self._put("write_status", t_ns, status)

    def close(self, timeout: float = 30.0) -> bool:
        """Let the child write what is queued and the footer, then join it.

        Returns True if the file was closed cleanly, False if the child had died
        (the file then ends at its last complete chunk).
        """
        if self._closed:
            return self._proc.exitcode == 0
        self._closed = True
        if self._proc.is_alive():
            try:
                self._queue.put(None, timeout=timeout)
            except queue.Full:
                log.error("recorder: queue still full after %.0f s, terminating it", timeout)
            self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join()
        clean = self._proc.exitcode == 0
        if not clean:
            log.error("recorder process died (exit code %s); %d writes dropped", self._proc.exitcode, self.dropped)
            self._queue.cancel_join_thread()  # nobody will read what is left in the pipe
        self._queue.close()
        return clean

    def __enter__(self) -> RecorderProcess:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


class RawMessage(NamedTuple):
    """One message as stored: its topic, times and JSON bytes, not decoded."""

    topic: str
    log_time: int
    publish_time: int
    data: bytes


@dataclass
class LogContents:
    """What :func:`read_log` recovered: ``raw`` messages in log-time order, decoded on demand."""

    raw: list[RawMessage]
    complete: bool
    """False if the file has no footer (recorder killed) or is damaged; ``raw`` then holds every complete chunk."""
    error: str | None = None
    """Why reading stopped before the footer, if it did."""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    @cached_property
    def messages(self) -> list[tuple[str, int, dict[str, Any]]]:
        """Every message as ``(topic, log_time_ns, dict)``, in log-time order."""
        return [(m.topic, m.log_time, loads(m.data)) for m in self.raw]

    @property
    def records(self) -> int:
        return len(self.raw)

    def of(self, topics: Iterable[str]) -> list[RawMessage]:
        """The raw messages of some topics, in log-time order."""
        wanted = set(topics)
        return [m for m in self.raw if m.topic in wanted]

    def topic(self, name: str) -> list[tuple[int, dict[str, Any]]]:
        """``(log_time_ns, dict)`` of one topic."""
        return [(m.log_time, loads(m.data)) for m in self.of((name,))]

    def inputs(self) -> list[tuple[Sample, int]]:
        """Input samples and their receive times, in log-time order."""
        return [decode_sample(m.topic, loads(m.data)) for m in self.of(INPUT_TOPICS)]

    def estimates(self) -> list[Estimate]:
        return [Estimate.from_dict(d) for _, d in self.topic("/estimate")]

    def truth(self) -> list[tuple[int, Quat]]:
        """``(t_ns, q_wxyz)`` from ``/truth/pose``."""
        return [(t, _quat_wxyz(d)) for t, d in self.topic("/truth/pose")]

    def status(self) -> list[tuple[int, dict[str, Any]]]:
        return self.topic("/status")

    def describe(self) -> str:
        state = "complete" if self.complete else f"INCOMPLETE ({self.error}); recovered every complete chunk"
        return f"{self.records} records, {state}"


def _quat_wxyz(pose: dict[str, Any]) -> Quat:
    o = pose["pose"]["orientation"]
    return (o["w"], o["x"], o["y"], o["z"])


_RECORD = struct.Struct("<BQ")
"""Opcode and length of every MCAP record."""
_MESSAGE = struct.Struct("<HIQQ")
"""Channel id, sequence, log time and publish time: the fixed part of a Message record."""


class _LogReader(StreamReader):
    """mcap's StreamReader, skipping (not parsing) the indexes: read_log reads the data in file order."""

    _SKIPPED = frozenset({Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX, Opcode.METADATA_INDEX,
                          Opcode.STATISTICS, Opcode.SUMMARY_OFFSET})

    def _read_record(self, opcode: int, length: int) -> McapRecord | None:
        if opcode in self._SKIPPED:
            return None  # the caller reads the whole length as padding (CRC included)
        return super()._read_record(opcode, length)


def _chunk_messages(chunk: Chunk, channels: dict[int, str]) -> list[RawMessage]:
    """The messages of a chunk (its CRC checked), registering the channels it declares.

    mcap's own reader builds a record object per message; parsing the message
    headers here with one ``unpack_from`` each is several times faster.
    """
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    out: list[RawMessage] = []
    pos = 0
    while pos < size:
        opcode, length = _RECORD.unpack_from(data, pos)
        pos += _RECORD.size
        end = pos + length
        if end > size:
            raise ValueError(f"record of {length} bytes overruns its chunk")
        if opcode == Opcode.MESSAGE:
            channel_id, _, log_time, publish_time = _MESSAGE.unpack_from(data, pos)
            out.append(RawMessage(channels[channel_id], log_time, publish_time, data[pos + _MESSAGE.size : end]))
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(ReadDataStream(BytesIO(data[pos:end])))
            channels[channel.id] = channel.topic
        pos = end
    return out


def read_log(path: str | Path) -> LogContents:
    """Read an MCAP log, complete or cut short (killed recorder, truncated copy).

    Records are read in file order with chunk CRCs checked; a chunk is
    kept only whole, so reading stops at the first incomplete or damaged
    record and everything before it is kept. Messages stay JSON bytes
    until asked for (:class:`LogContents`).
    """
    channels: dict[int, str] = {}
    raw: list[RawMessage] = []
    metadata: dict[str, dict[str, str]] = {}
    complete, error = False, None
    size = os.path.getsize(path)
    with open(path, "rb") as f:
        try:
            for rec in _LogReader(f, emit_chunks=True, validate_crcs=True, record_size_limit=size).records:
                if isinstance(rec, Chunk):
                    raw += _chunk_messages(rec, channels)
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    raw.append(RawMessage(channels[rec.channel_id], rec.log_time, rec.publish_time, rec.data))
                elif isinstance(rec, Metadata):
                    metadata[rec.name] = dict(rec.metadata)
            complete = True  # the reader stops only after the footer and the closing magic
        except Exception as e:  # noqa: BLE001 - any damage ends recovery; what came before is kept
            error = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
    raw.sort(key=itemgetter(1))  # stable: equal log times keep file order
    return LogContents(raw, complete, error, metadata)
