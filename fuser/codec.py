"""JSON encoding of input samples and estimates, shared by the recorder, replay and zenoh.

JSON because every consumer can read it (Foxglove shows JSON channels with a
JSON schema; a zenoh subscriber in any language needs nothing but a JSON
parser), and the messages are small. Encoding is deterministic: keys in a
fixed order and floats as Python's shortest round-trip repr, so the same
estimate always gives the same bytes and a replay can be compared byte for
byte.

The bytes are those of the standard library's encoder (compact separators,
ASCII, NaN and infinity refused); orjson writes most messages six times
faster, and its output is used only where it provably equals the standard
library's (:func:`dumps`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import orjson

from drivers.samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample, SourceId

__all__ = ["Estimate", "MalformedPayload", "decode_sample", "dumps", "encode_sample", "loads", "sample_channel", "sample_json"]


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)
_ORJSON_OPTIONS = orjson.OPT_PASSTHROUGH_DATACLASS | orjson.OPT_PASSTHROUGH_DATETIME | orjson.OPT_PASSTHROUGH_SUBCLASS
"""Dataclasses, datetimes and subclasses of str, int, dict, list: orjson refuses them, as (or where) the standard library does."""


def _orjson_if_identical(obj: Any, nones: int = 0) -> bytes | None:
    """orjson's encoding of ``obj`` where it is byte for byte the standard library's, else None.

    Both print a float as the shortest digits that round-trip (CPython's ``repr``), in the same
    notation except below 1e-4, where orjson writes ``1e-5`` as ``0.00001`` and ``1.5e-07`` as
    ``1.5e-7``: any ``e-`` or ``0.0000`` sends the message to the standard library. orjson
    writes NaN and infinity as ``null`` where the standard library refuses them, so the output
    may hold no more nulls than ``nones``, a count of None values that ``obj`` certainly holds
    (each writes one null: any other null is a NaN, an infinity or text). Any non-ASCII byte or
    DEL, which the standard library escapes, sends it there too. orjson refuses (raises)
    integers beyond 64 bits, non-string keys and nesting deeper than 254: the standard library
    encodes those.
    """
    try:
        out = orjson.dumps(obj, option=_ORJSON_OPTIONS)
    except orjson.JSONEncodeError:
        return None
    if b"e-" in out or b"0.0000" in out or b"\x7f" in out or not out.isascii() or out.count(b"null") != nones:
        return None
    return out


def dumps(obj: Any) -> bytes:
    """Deterministic compact JSON bytes: ``json.JSONEncoder(separators=(",", ":"), allow_nan=False)``'s, as UTF-8.

    One difference in what is accepted: an ``enum.Enum`` or ``uuid.UUID`` (which the standard
    library refuses) is written as its value by orjson.
    """
    out = _orjson_if_identical(obj)
    return _ENCODER.encode(obj).encode() if out is None else out


_DIGITS = bytes.maketrans(b"123456789", b"000000000")
_LONG_INTEGERS = (b"0" * 20, b"-" + b"0" * 19)
"""Digit runs that may be an integer beyond 64 bits (orjson parses those as floats; 20 digits
also occur in a float's repr between 1e-4 and 1e-3, which then just takes the slow path)."""


def loads(data: bytes) -> Any:
    """``json.loads(data)``, three times faster where orjson gives the same objects.

    orjson parses floats correctly rounded, as the standard library does; it parses integers
    beyond 64 bits as floats, so any run of 20 digits (19 after a minus) goes to the standard
    library, and so does anything orjson refuses (NaN and Infinity literals, numbers beyond
    the float range, lone surrogates, other encodings than UTF-8), with the standard library's
    result or error.
    """
    shape = data.translate(_DIGITS)
    if _LONG_INTEGERS[0] in shape or _LONG_INTEGERS[1] in shape:
        return json.loads(data)
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError:
        return json.loads(data)


def _source(s: SourceId) -> dict[str, Any]:
    return {"transport": s.transport, "system": s.system, "component": s.component, "instance": s.instance}


def sample_channel(sample: Sample) -> str:
    """MCAP topic of a sample type."""
    return _CHANNELS[type(sample)]


_CHANNELS = {ImuSample: "/input/imu", MagSample: "/input/mag", AttitudeSample: "/input/attitude", GnssSample: "/input/gnss"}
_GNSS_FIELDS = ("fix_type", "vertical_velocity", "speed_accuracy_m_s", "lat_deg", "lon_deg", "alt_m", "filtered")


def encode_sample(sample: Sample, receive_ns: int) -> dict[str, Any]:
    """A sample as a JSON-able dict, with the time the fuser received it."""
    out: dict[str, Any] = {"t_ns": sample.t_ns, "receive_ns": receive_ns, "source": _source(sample.source)}
    if isinstance(sample, ImuSample):
        out["gyro_rad_s"] = list(sample.gyro_rad_s)
        out["accel_m_s2"] = list(sample.accel_m_s2)
        out["mag_gauss"] = None if sample.mag_gauss is None else list(sample.mag_gauss)
    elif isinstance(sample, MagSample):
        out["mag_gauss"] = list(sample.mag_gauss)
    elif isinstance(sample, GnssSample):
        out["vel_ned_m_s"] = None if sample.vel_ned_m_s is None else list(sample.vel_ned_m_s)
        for name in _GNSS_FIELDS:
            out[name] = getattr(sample, name)
    else:
        out["q_wxyz"] = list(sample.q_wxyz)
    return out


def sample_json(sample: Sample, receive_ns: int) -> bytes:
    """``dumps(encode_sample(sample, receive_ns))``, without the standard library's encoder for the None
    fields a sample may have (an IMU without magnetometer, a GNSS fix without position)."""
    d = encode_sample(sample, receive_ns)
    out = _orjson_if_identical(d, sum(v is None for v in d.values()))
    return _ENCODER.encode(d).encode() if out is None else out


@lru_cache(maxsize=1024)
def _source_id(transport: str, system: int, component: int, instance: int) -> SourceId:
    """One shared SourceId per source: decoding a log makes few distinct ones, many times."""
    return SourceId(transport, system, component, instance)


def _vec(values: list[Any]) -> tuple[float, ...]:
    return tuple(map(float, values))


def decode_sample(topic: str, d: dict[str, Any]) -> tuple[Sample, int]:
    """Inverse of :func:`encode_sample`: the sample and its receive time."""
    s = d["source"]
    src = _source_id(s["transport"], s["system"], s["component"], s["instance"])
    t_ns = int(d["t_ns"])
    if topic == "/input/imu":
        mag = d.get("mag_gauss")
        sample: Sample = ImuSample(t_ns, _vec(d["gyro_rad_s"]), _vec(d["accel_m_s2"]), None if mag is None else _vec(mag), src)  # type: ignore[arg-type]
    elif topic == "/input/mag":
        sample = MagSample(t_ns, _vec(d["mag_gauss"]), src)  # type: ignore[arg-type]
    elif topic == "/input/attitude":
        sample = AttitudeSample(t_ns, _vec(d["q_wxyz"]), src)  # type: ignore[arg-type]
    elif topic == "/input/gnss":
        vel = d["vel_ned_m_s"]
        sample = GnssSample(t_ns, vel_ned_m_s=None if vel is None else _vec(vel), source=src,  # type: ignore[arg-type]
                            **{name: d[name] for name in _GNSS_FIELDS})
    else:
        raise ValueError(f"not an input topic: {topic}")
    return sample, int(d["receive_ns"])


@dataclass(frozen=True)
class Estimate:
    """One fused attitude estimate, stamped with its tick time (ns, the loop's timeline).

    ``q_wxyz`` rotates body FRD into world NED. ``M`` (4x4, row-major) and
    ``Z`` are the full Bingham posterior; ``uncertainty_deg`` its RMS
    angular deviation; ``euler_deg`` roll, pitch, yaw (ZYX) for convenience.
    ``sensor_t_ns`` is the tick time on the clock of the reference IMU (the
    loop's first IMU stream; the sender's own time), to line estimates up with
    autopilot logs. ``predicted``: made by the output predictor between two ticks
    (``[fuser.extrapolation] every_imu_sample``, :mod:`fuser.model.output`: the last
    tick's state turned by the gyro to a later IMU sample), not by a tick of the
    filter. ``diagnostics`` says what each measurement update did in
    the tick (:class:`fuser.model.diagnostics.UpdateDiagnostic` as dicts); it
    is not part of the estimate's payload but recorded beside it on
    ``/diagnostics`` (:meth:`diagnostics_dict`).
    """

    t_ns: int
    q_wxyz: tuple[float, float, float, float]
    M: tuple[tuple[float, ...], ...]
    Z: tuple[float, float, float, float]
    uncertainty_deg: float
    euler_deg: tuple[float, float, float]
    counters: dict[str, int] = field(default_factory=dict)
    sensor_t_ns: int | None = None
    predicted: bool = False
    diagnostics: tuple[dict[str, Any], ...] = field(default=(), compare=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "t_ns": self.t_ns,
            "q_wxyz": list(self.q_wxyz),
            "M": [list(r) for r in self.M],
            "Z": list(self.Z),
            "uncertainty_deg": self.uncertainty_deg,
            "euler_deg": list(self.euler_deg),
            "counters": dict(sorted(self.counters.items())),
            "sensor_t_ns": self.sensor_t_ns,
            "predicted": self.predicted,
        }

    def to_json(self) -> bytes:
        """The estimate as published and recorded (``dumps`` of :meth:`to_dict`)."""
        return dumps(self.to_dict())

    def diagnostics_dict(self) -> dict[str, Any]:
        """The tick's update diagnostics as recorded on ``/diagnostics``: ``{"t_ns", "updates": [...]}``."""
        return {"t_ns": self.t_ns, "updates": list(self.diagnostics)}

    @classmethod
    def from_dict(cls, d: Any) -> Estimate:
        """The estimate a payload's object holds (:meth:`to_dict`'s layout, fuser/IO.md), its numbers as they were
        (so that :meth:`to_json` gives the same bytes back); :class:`MalformedPayload` naming the first field
        that is missing or not what the layout says."""
        if not isinstance(d, dict):
            raise MalformedPayload("not a JSON object")
        for name in _REQUIRED:
            if name not in d:
                raise MalformedPayload(f"no {name}")
        counters = d.get("counters", {})
        if not (isinstance(counters, dict) and all(_is_integer(v) for v in counters.values())):
            raise MalformedPayload("counters: expected an object of integers")
        sensor_t_ns = d.get("sensor_t_ns")
        if not (sensor_t_ns is None or _is_integer(sensor_t_ns)):
            raise MalformedPayload("sensor_t_ns: expected an integer or null")
        predicted = d.get("predicted", False)
        if not isinstance(predicted, bool):
            raise MalformedPayload("predicted: expected true or false")
        if not _is_integer(d["t_ns"]):
            raise MalformedPayload("t_ns: expected an integer")
        uncertainty = d["uncertainty_deg"]
        if not (_is_number(uncertainty) and uncertainty >= 0):
            raise MalformedPayload("uncertainty_deg: expected a finite number >= 0")
        rows, M = "M: expected 4 rows of 4 finite numbers", d["M"]
        if not (isinstance(M, list) and len(M) == 4):
            raise MalformedPayload(rows)
        return cls(
            d["t_ns"],
            _numbers(d["q_wxyz"], 4, "q_wxyz: expected 4 finite numbers"),  # type: ignore[arg-type]
            tuple(_numbers(row, 4, rows) for row in M),
            _numbers(d["Z"], 4, "Z: expected 4 finite numbers"),  # type: ignore[arg-type]
            uncertainty,
            _numbers(d["euler_deg"], 3, "euler_deg: expected 3 finite numbers"),  # type: ignore[arg-type]
            dict(counters),
            sensor_t_ns,
            predicted,
        )

    @classmethod
    def from_json(cls, payload: bytes) -> Estimate:
        """The estimate published or recorded as ``payload`` (:meth:`to_json`); :class:`MalformedPayload` if it is
        not one (not JSON, not UTF-8, or not the layout)."""
        try:
            d = loads(payload)
        except (ValueError, RecursionError):  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            raise MalformedPayload("not JSON") from None
        return cls.from_dict(d)


class MalformedPayload(ValueError):
    """A payload that is not what its key or channel carries (an estimate, a status); the message names what is
    wrong in a few words, from a fixed set (so that a subscriber can count them by it)."""


_REQUIRED = ("t_ns", "q_wxyz", "M", "Z", "uncertainty_deg", "euler_deg")
"""The fields every estimate has (fuser/IO.md); ``counters``, ``sensor_t_ns`` and ``predicted`` may be left out."""
_INT64 = 1 << 63


def _is_integer(value: Any) -> bool:
    """A JSON integer within int64 (``true`` and ``false`` are not numbers here)."""
    return isinstance(value, int) and not isinstance(value, bool) and -_INT64 <= value < _INT64


def _is_number(value: Any) -> bool:
    """A finite float or an int64 (``NaN`` and ``Infinity``, which Python's parser takes, are not)."""
    return (isinstance(value, float) and math.isfinite(value)) or _is_integer(value)


def _numbers(value: Any, n: int, wrong: str) -> tuple[Any, ...]:
    """``value``, a list of ``n`` finite numbers, as a tuple; :class:`MalformedPayload` saying ``wrong`` otherwise."""
    if not (isinstance(value, list) and len(value) == n and all(_is_number(v) for v in value)):
        raise MalformedPayload(wrong)
    return tuple(value)
