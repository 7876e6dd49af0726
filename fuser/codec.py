"""JSON encoding of input samples and estimates, shared by the recorder, replay and zenoh.

JSON because every consumer can read it (Foxglove shows JSON channels with a
JSON schema; a zenoh subscriber in any language needs nothing but a JSON
parser), and the messages are small. Encoding is deterministic: keys in a
fixed order and floats as Python's shortest round-trip repr, so the same
estimate always gives the same bytes and a replay can be compared byte for
byte.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

from drivers.samples import AttitudeSample, GnssSample, ImuSample, MagSample, Sample, SourceId

__all__ = ["Estimate", "decode_sample", "dumps", "encode_sample", "sample_channel"]


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def dumps(obj: Any) -> bytes:
    """Deterministic compact JSON bytes."""
    return _ENCODER.encode(obj).encode()


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
    autopilot logs. ``diagnostics`` says what each measurement update did in
    the tick (:class:`fuser.model.diagnostics.UpdateDiagnostic` as dicts); it
    is not part of the estimate's payload but recorded beside it on
    ``/diagnostics`` (:meth:`diagnostics_json`).
    """

    t_ns: int
    q_wxyz: tuple[float, float, float, float]
    M: tuple[tuple[float, ...], ...]
    Z: tuple[float, float, float, float]
    uncertainty_deg: float
    euler_deg: tuple[float, float, float]
    counters: dict[str, int] = field(default_factory=dict)
    sensor_t_ns: int | None = None
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
        }

    def to_json(self) -> bytes:
        """The estimate as published and recorded (``dumps`` of :meth:`to_dict`)."""
        return dumps(self.to_dict())

    def diagnostics_json(self) -> bytes:
        """The tick's update diagnostics as recorded on ``/diagnostics``: ``{"t_ns", "updates": [...]}``."""
        return dumps({"t_ns": self.t_ns, "updates": list(self.diagnostics)})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Estimate:
        return cls(
            int(d["t_ns"]),
            tuple(d["q_wxyz"]),  # type: ignore[arg-type]
            tuple(tuple(r) for r in d["M"]),
            tuple(d["Z"]),  # type: ignore[arg-type]
            float(d["uncertainty_deg"]),
            tuple(d["euler_deg"]),  # type: ignore[arg-type]
            dict(d.get("counters", {})),
            d.get("sensor_t_ns"),
        )
