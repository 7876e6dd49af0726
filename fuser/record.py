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

import contextlib
import logging
import math
import multiprocessing as mp
import os
import queue
import signal
from collections import Counter
from dataclasses import dataclass, field
from functools import cached_property
from heapq import heappop, heappush
from operator import index, itemgetter
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO, Iterable, Iterator

from mcap.writer import CompressionType, Writer

from drivers.samples import Quat, Sample

from .codec import Estimate, decode_sample, dumps, loads, sample_channel, sample_json
from .errors import FuserError, os_reason
from .frames import BODY_FRAME, TRUTH_OFFSET_NED_M, body_transforms
from .mcap_scan import McapStream, NotAnMcapError, RawMessage, Skipped, scan_mcap

__all__ = ["CHANNELS", "LogContents", "LogOverview", "LogStream", "McapRecorder", "NotAnMcapError", "RawMessage", "RecorderProcess", "frame_transforms",
           "pose_in_frame", "read_log"]

log = logging.getLogger(__name__)

FRAME_ID = "ned"
U64_MAX = (1 << 64) - 1
"""MCAP stores log and publish times as uint64 nanoseconds."""
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


# Foxglove's schemas (github.com/foxglove/foxglove-sdk, schemas/jsonschema/PoseInFrame.json, FrameTransforms.json): the same
# fields, types, bounds and required fields (every object's but the time's); their own descriptions of the vectors left out.
POSE_IN_FRAME = _obj(
    "foxglove.PoseInFrame",
    "A timestamped pose for an object or reference frame in 3D space",
    {
        "timestamp": _obj(
            "time",
            "Timestamp of pose",
            {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}},
            required=False,  # as in Foxglove's schema: its time lists no required fields
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

_TIME = {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}
FRAME_TRANSFORMS = _obj(
    "foxglove.FrameTransforms",
    "An array of FrameTransform messages",
    {
        "transforms": {
            "type": "array",
            "description": "Array of transforms",
            "items": _obj(
                "foxglove.FrameTransform",
                "A transform between two reference frames in 3D space",
                {
                    "timestamp": _obj("time", "Timestamp of transform", _TIME, required=False),
                    "parent_frame_id": {"type": "string", "description": "Name of the parent frame"},
                    "child_frame_id": {"type": "string", "description": "Name of the child frame"},
                    "translation": _vec("xyz", "foxglove.Vector3"),
                    "rotation": _vec("xyzw", "foxglove.Quaternion"),
                },
            ),
        }
    },
)
"""Foxglove's ``foxglove.FrameTransforms`` (its published JSON schema's fields): ``enu -> ned -> body`` per estimate."""
TRUTH_FRAME = "truth_body"

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
    "Fused attitude: Bingham posterior at one loop tick, or carried by the gyro to a later IMU sample",
    {
        "t_ns": {"type": "integer", "description": "the time the estimate is for, ns"},
        "q_wxyz": _array(4, "unit quaternion w,x,y,z rotating body FRD into world NED"),
        "M": {"type": "array", "items": _array(4, "row"), "minItems": 4, "maxItems": 4, "description": "Bingham M, 4x4 row-major, columns are the axes"},
        "Z": _array(4, "Bingham concentrations, one per column of M (<= 0)"),
        "uncertainty_deg": {"type": "number", "description": "RMS angular deviation, degrees"},
        "euler_deg": _array(3, "roll, pitch, yaw (ZYX), degrees"),
        "counters": {"type": "object", "additionalProperties": _INT},
        "sensor_t_ns": {"type": ["integer", "null"], "description": "the same instant on the reference IMU's clock, ns"},
        "predicted": {"type": "boolean", "description": "made by the output predictor between ticks, not by a tick"},
    },
)

_NUM_OR_NULL = {"type": ["number", "null"]}
DIAGNOSTIC_UPDATES = ("mag_field", "velocity", "gravity", "heading", "attitude")
"""Every update a ``/diagnostics`` record can list (``fuser.model.diagnostics.UPDATES``, and ``mag_field``)."""
DIAGNOSTICS = _obj(
    "bingham_fuser.Diagnostics",
    "What each measurement update did in one tick (fuser/model/diagnostics.py)",
    {
        "t_ns": {"type": "integer", "description": "tick time, ns"},
        "updates": {"type": "array", "items": _obj("update", "one update's outcome", {
            "update": {"type": "string", "enum": list(DIAGNOSTIC_UPDATES), "description": (
                "gravity (accelerometer), heading (magnetometer), attitude (the autopilot's), velocity (a GNSS fix, as the "
                "world acceleration it gives), mag_field (the reference field replaced, e.g. by the WMM's at the first fix)")},
            "outcome": {"enum": ["fused", "gated", "reanchored"]},
            "reason": {"type": "string", "description": (
                "why gated: norm, dip, innovation, before_tilt; for velocity no_fix, stale, gap, jump, unselected, unconverged; "
                "for mag_field the field's source (config, wmm, fallback) or out_of_range; empty otherwise")},
            "innovation_deg": {**_NUM_OR_NULL, "description": "angle between measurement and prediction, degrees"},
            "sigma_deg": {**_NUM_OR_NULL, "description": "measurement sigma used, degrees"},
            "test_ratio": {**_NUM_OR_NULL, "description": "(innovation / gate)^2: above 1 outside the gate"},
        })},
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
    "/tf": FRAME_TRANSFORMS,
    "/diagnostics": DIAGNOSTICS,
}


def pose_in_frame(t_ns: int, q_wxyz: Quat, position_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict[str, Any]:
    """A ``foxglove.PoseInFrame`` dict (orientation in x, y, z, w order) in NED, at the origin by default."""
    w, x, y, z = q_wxyz
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": FRAME_ID,
        "pose": {"position": dict(zip("xyz", position_ned_m)), "orientation": {"x": x, "y": y, "z": z, "w": w}},
    }


def frame_transforms(t_ns: int, child_frame: str, q_wxyz: Quat, translation_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
                     ) -> dict[str, Any]:
    """A ``foxglove.FrameTransforms`` dict placing ``child_frame`` in the upright ``enu`` frame (``fuser.frames``)."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return {"transforms": [
        {"timestamp": {"sec": sec, "nsec": nsec}, "parent_frame_id": parent, "child_frame_id": child,
         "translation": dict(zip("xyz", t)), "rotation": dict(zip("xyzw", r))}
        for parent, child, t, r in body_transforms(child_frame, q_wxyz, translation_ned_m)
    ]}


WRITE_FAILED_EXIT = 3
"""The recorder process's exit code when its file could not be written (:class:`RecordWriteError`)."""


class RecordWriteError(FuserError):
    """The recording's file ``path`` cannot be written: ``reason`` (a full disk, an I/O error); ``kept`` says what it
    holds, if anything."""

    def __init__(self, path: Path, reason: str, kept: str = "") -> None:
        super().__init__(f"cannot write {path}: {reason}{kept}")
        self.path, self.reason = path, reason


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
    to the file, i.e. what survives if the process is killed now. A record the
    file cannot hold (a time outside uint64, a value JSON cannot encode such as
    NaN) is checked for before it reaches the writer, so it cannot leave half a
    record in a chunk: it is not written, it is counted in ``rejected`` by
    reason, the first one is logged, and recording goes on. So is a write the
    writer fails (``write_failed``), unless ``stop_on_write_error``: then it
    raises :class:`RecordWriteError`, for a file that is the command's whole
    product (a replay's, an import's), which a full disk would leave
    incomplete at every later chunk. Finishing the file (:meth:`close`) raises
    it in every case, naming the file.
    """

    def __init__(self, path: str | Path, chunk_size: int = 64 * 1024, metadata: dict[str, str] | None = None,
                 stop_on_write_error: bool = False) -> None:
        self.path = Path(path)
        self._stop_on_write_error = stop_on_write_error
        self._file = open(path, "wb")
        self._output = _ChunkOutput(self._file)
        self._writer = Writer(self._output, chunk_size=chunk_size, compression=CompressionType.ZSTD, enable_data_crcs=True)  # type: ignore[arg-type]
        self._writer.start(profile="", library="bingham-fuser")
        if metadata:
            self.add_metadata("bingham_fuser", metadata)
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
        try:
            self._file.flush()
        except OSError as e:  # a disk already full: no record can follow
            with contextlib.suppress(OSError):
                self._file.close()
            raise RecordWriteError(self.path, os_reason(e)) from e
        self._output.wrote = False
        self.records_on_disk = 0
        self.rejected: Counter[str] = Counter()
        """Records not written, by reason: ``time_out_of_range``, ``not_json``, ``write_failed``."""
        self.closed = False

    def add_metadata(self, name: str, metadata: dict[str, str]) -> None:
        """A metadata record ``name`` (keys sorted); :attr:`LogContents.metadata` reads it back by name."""
        self._writer.add_metadata(name, dict(sorted(metadata.items())))

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    def health(self) -> dict[str, Any]:
        """The recorder's entry in the status, as :meth:`RecorderProcess.health`'s (in process, nothing is dropped)."""
        return {"alive": not self.closed, "dropped": 0, "rejected": self.rejected_total}

    def _reject(self, topic: str, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        if self.rejected_total == 1:
            log.warning("recorder: a %s record was not written (%s); recording goes on, further ones are only counted "
                        "(recorder.rejected)", topic, detail)

    def write_message(self, topic: str, log_time: int, publish_time: int, data: bytes) -> bool:
        """One message already encoded as JSON (e.g. copied unchanged from another log); False if rejected."""
        try:
            times = index(log_time), index(publish_time)
        except TypeError:
            self._reject(topic, "time_out_of_range", f"times {log_time!r}, {publish_time!r} are not integers")
            return False
        if not (0 <= times[0] <= U64_MAX and 0 <= times[1] <= U64_MAX):
            self._reject(topic, "time_out_of_range", f"log time {times[0]} or publish time {times[1]} ns outside uint64")
            return False
        seq = self._sequence[topic] + 1
        try:
            self._writer.add_message(self._channels[topic], times[0], data, times[1], seq)
            chunk_closed, self._output.wrote = self._output.wrote, False
            if chunk_closed:  # the chunk just closed goes to the OS at once
                self._file.flush()
        except Exception as e:  # noqa: BLE001 - a disk or writer failure costs this record, not the recording
            if self._stop_on_write_error:
                raise RecordWriteError(self.path, os_reason(e)) from e
            self._reject(topic, "write_failed", f"{type(e).__name__}: {e}")
            return False
        self._sequence[topic] = seq
        self._count += 1
        if chunk_closed:
            self.records_on_disk = self._count
        return True

    def _encode(self, topic: str, payload: Any) -> bytes | None:
        try:
            return dumps(payload)
        except (TypeError, ValueError) as e:  # NaN or infinity (allow_nan=False), or a value JSON has no form for
            self._reject(topic, "not_json", str(e))
            return None

    def write_sample(self, sample: Sample, receive_ns: int) -> None:
        """An input sample; log time = receive time, publish time = the sender's time."""
        topic = sample_channel(sample)
        try:
            data = sample_json(sample, receive_ns)
        except (TypeError, ValueError) as e:  # NaN or infinity (refused), or a value JSON has no form for
            self._reject(topic, "not_json", str(e))
            return
        self.write_message(topic, receive_ns, sample.t_ns, data)

    def write_estimate(self, est: Estimate) -> None:
        """An estimate on ``/estimate`` (full), ``/pose`` and ``/tf`` (Foxglove), and its tick's update diagnostics
        on ``/diagnostics`` (every tick that ran an update), at its time. The output predictor's estimates between
        ticks go on ``/estimate`` alone: the Foxglove views follow the ticks (100 Hz by default), which a viewer
        needs, not every IMU sample, which would triple what a replay writes."""
        full = self._encode("/estimate", est.to_dict())
        views = () if est.predicted else (("/pose", self._encode("/pose", pose_in_frame(est.t_ns, est.q_wxyz))),
                                          ("/tf", self._encode("/tf", frame_transforms(est.t_ns, BODY_FRAME, est.q_wxyz))))
        # one estimate, one verdict: its Foxglove views and diagnostics are written only with the estimate itself
        if full is None or any(data is None for _, data in views) or not self.write_message("/estimate", est.t_ns, est.t_ns, full):
            return
        for topic, data in views:
            self.write_message(topic, est.t_ns, est.t_ns, data)
        if est.diagnostics and (data := self._encode("/diagnostics", est.diagnostics_dict())) is not None:
            self.write_message("/diagnostics", est.t_ns, est.t_ns, data)

    def write_truth(self, t_ns: int, q_wxyz: Quat, log_time_ns: int | None = None) -> None:
        """The true attitude (simulator, imported logs) on ``/truth/pose``, and its own body frame on ``/tf``.

        ``t_ns`` is the instant on the vehicle's clock (the publish time, what
        scoring compares ``sensor_t_ns`` with); ``log_time_ns`` the same instant
        on the recording's timeline (the log time and the pose's timestamp),
        by default ``t_ns``.
        """
        log_time = t_ns if log_time_ns is None else log_time_ns
        pose = self._encode("/truth/pose", pose_in_frame(log_time, q_wxyz, TRUTH_OFFSET_NED_M))
        tf = self._encode("/tf", frame_transforms(log_time, TRUTH_FRAME, q_wxyz, TRUTH_OFFSET_NED_M))
        if pose is not None and tf is not None and self.write_message("/truth/pose", log_time, t_ns, pose):
            self.write_message("/tf", log_time, t_ns, tf)

    def write_status(self, t_ns: int, status: dict[str, Any]) -> None:
        """A health/counters dict on ``/status``."""
        data = self._encode("/status", status)
        if data is not None:
            self.write_message("/status", t_ns, t_ns, data)

    def close(self) -> None:
        """Write the last chunk, the summary and the footer; idempotent."""
        if self.closed:
            return
        self.closed = True
        try:
            try:
                self._writer.finish()
            finally:
                self._file.close()  # closed even when its last flush fails
        except OSError as e:  # a full disk: what is on it stays readable up to its last complete chunk (read_log)
            raise RecordWriteError(self.path, os_reason(e), f"; it holds at least the {self.records_on_disk:,} records written before "
                                   "(up to its last complete chunk)") from e
        self.records_on_disk = self._count

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


def _record_child(
    path: str, chunk_size: int, metadata: dict[str, str] | None, q: mp.Queue, on_disk: Any, rejected: Any, parent: int
) -> None:
    """Child process: apply queued ``(method, args)`` calls until ``None`` or the parent is gone.

    A call that fails is counted with the recorder's own rejections and the
    child goes on: no single record ends the recording.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the parent, which closes us cleanly
    failed = 0
    try:
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
                try:
                    getattr(rec, method)(*args)
                except Exception as e:  # noqa: BLE001 - the recorder must outlive any one record
                    failed += 1
                    if failed == 1:
                        log.warning("recorder: %s failed (%s: %s); recording goes on", method, type(e).__name__, e)
                on_disk.value = rec.records_on_disk
                rejected.value = rec.rejected_total + failed
    except RecordWriteError as e:  # the file could not be finished (a full disk): one line, and the exit code says why
        log.error("recorder: %s", e)
        raise SystemExit(WRITE_FAILED_EXIT) from None
    on_disk.value = rec.records_on_disk


class RecorderProcess:
    """The :class:`McapRecorder` API, forwarded to a recorder in a child process.

    Writes never block nor raise: when the queue is full or the child is dead
    the call is counted in ``dropped``. ``records_on_disk`` is how many
    records the child has in complete chunks on disk, ``rejected`` how many
    it refused (see :class:`McapRecorder`) or failed to write.
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
        self._rejected = ctx.RawValue("q", 0)
        self._proc = ctx.Process(
            target=_record_child,
            args=(str(path), chunk_size, metadata, self._queue, self._on_disk, self._rejected, os.getpid()),
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

    @property
    def rejected(self) -> int:
        """Records the child refused or failed to write (it goes on recording)."""
        return int(self._rejected.value)

    def health(self) -> dict[str, Any]:
        """The recorder's entry in the status: the child alive, writes dropped, records refused."""
        return {"alive": self.alive, "dropped": self.dropped, "rejected": self.rejected}

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

    def write_truth(self, t_ns: int, q_wxyz: Quat, log_time_ns: int | None = None) -> None:
        self._put("write_truth", t_ns, tuple(q_wxyz), log_time_ns)

    def write_status(self, t_ns: int, status: dict[str, Any]) -> None:
        self._put("write_status", t_ns, status)

    @property
    def write_failed(self) -> bool:
        """True once the child has ended because its file could not be written (a full disk, an I/O error)."""
        return self._proc.exitcode == WRITE_FAILED_EXIT

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
        if self.write_failed:
            self._queue.cancel_join_thread()
        elif not clean:
            log.error("recorder process died (exit code %s); %d writes dropped", self._proc.exitcode, self.dropped)
            self._queue.cancel_join_thread()  # nobody will read what is left in the pipe
        self._queue.close()
        return clean

    def __enter__(self) -> RecorderProcess:
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()


@dataclass
class LogContents:
    """What :func:`read_log` recovered: ``raw`` messages in log-time order, decoded on demand."""

    raw: list[RawMessage]
    complete: bool
    """False if the file has no footer (recorder killed) or is damaged; ``raw`` then holds every complete chunk."""
    error: str | None = None
    """Why reading stopped before the footer, or what was damaged."""
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    skipped: Skipped = field(default_factory=Skipped)
    """What a damaged file lost: chunks, bytes, messages (empty for a sound file)."""

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
        """``(t_ns, q_wxyz)`` from ``/truth/pose``, ``t_ns`` on the vehicle's clock (the publish time)."""
        return [(m.publish_time, _quat_wxyz(loads(m.data))) for m in self.of(("/truth/pose",))]

    def status(self) -> list[tuple[int, dict[str, Any]]]:
        return self.topic("/status")

    def describe(self) -> str:
        return _describe(self.records, self.complete, self.skipped, self.error)


def _describe(records: int, complete: bool, skipped: Skipped, error: str | None) -> str:
    """One line on what reading a log recovered (:meth:`LogContents.describe`, :meth:`LogOverview.describe`)."""
    if complete:
        return f"{records} records, complete"
    if skipped:
        return f"{records} records, DAMAGED: skipped {skipped.describe()}; read every sound chunk"
    return f"{records} records, INCOMPLETE ({error}); recovered every complete chunk"


def _quat_wxyz(pose: dict[str, Any]) -> Quat:
    o = pose["pose"]["orientation"]
    return (o["w"], o["x"], o["y"], o["z"])


def read_log(path: str | Path) -> LogContents:
    """Read an MCAP log, complete, cut short (killed recorder, truncated copy) or damaged.

    Records are read in file order with chunk CRCs checked (:func:`fuser.mcap_scan.scan_mcap`):
    a damaged chunk is skipped and counted in ``skipped``, and reading goes on
    with the next record; a file cut short keeps every complete chunk. Messages
    stay JSON bytes until asked for (:class:`LogContents`). Raises
    :class:`~fuser.mcap_scan.NotAnMcapError` if the file is not an MCAP at all.
    """
    scan = scan_mcap(path)
    raw = sorted(scan.messages, key=itemgetter(1))  # stable: equal log times keep file order
    return LogContents(raw, scan.complete, scan.error, scan.metadata, scan.skipped)


@dataclass(frozen=True)
class LogOverview:
    """What a pass over a log found, without its messages: :class:`LogContents` less ``raw``, and the count per topic."""

    complete: bool
    error: str | None
    metadata: dict[str, dict[str, str]]
    skipped: Skipped
    topics: Counter[str]
    """Messages per topic."""

    @property
    def records(self) -> int:
        return sum(self.topics.values())

    def count(self, topics: Iterable[str]) -> int:
        """Messages of some topics."""
        return sum(self.topics[t] for t in topics)

    def describe(self) -> str:
        return _describe(self.records, self.complete, self.skipped, self.error)


class LogStream:
    """An MCAP log, complete, cut short or damaged, read as :func:`read_log` reads it but as a stream: the same
    messages in the same order (log time; equal log times in file order), holding about one chunk at a time
    instead of the whole log, so that a log of any length is read in bounded memory.

    Opening it reads the file once (:attr:`overview`); each :meth:`messages` reads it again. A file written in
    log-time order (as this recorder writes it) is merged chunk by chunk; one that is not costs memory for the
    messages that arrive before their time, up to the whole log.
    """

    def __init__(self, path: str | Path) -> None:
        self._stream = McapStream(path)
        topics: Counter[str] = Counter()
        firsts = []
        for group in self._stream:
            topics.update(m.topic for m in group)
            firsts.append(min(m.log_time for m in group))
        scan = self._stream.result
        assert scan is not None  # set by the iteration that just ended
        self.overview = LogOverview(scan.complete, scan.error, scan.metadata, scan.skipped, topics)
        self._later = _later_minima(firsts)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """The messages (of some topics, or all) in log-time order, as ``read_log(path).of(topics)`` lists them.

        A message is let out once no later group of the file holds an earlier one (``_later``); a stable order by
        (log time, position in the file) among those held back keeps ``sorted``'s order for equal times.
        """
        wanted = None if topics is None else set(topics)
        held: list[tuple[int, int, RawMessage]] = []
        position = 0
        for group, later in zip(self._stream, self._later):
            for m in group:
                if wanted is None or m.topic in wanted:
                    heappush(held, (m.log_time, position, m))
                    position += 1
            while held and held[0][0] <= later:
                yield heappop(held)[2]


def _later_minima(firsts: list[int]) -> list[int | float]:
    """For each group, the earliest log time of the groups after it (infinity after the last)."""
    out: list[int | float] = [math.inf] * len(firsts)
    for i in range(len(firsts) - 2, -1, -1):
        out[i] = min(firsts[i + 1], out[i + 1])
    return out
