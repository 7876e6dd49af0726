"""A live Foxglove view of the running fuser, over Foxglove's WebSocket protocol (``foxglove-sdk``).

``--foxglove [PORT]`` serves, on ``ws://127.0.0.1:PORT`` (8765 by default; open it in Foxglove
with *Open connection...* -> *Foxglove WebSocket*):

| topic | schema (encoding) | content |
| --- | --- | --- |
| ``/tf`` | ``foxglove.FrameTransforms`` (protobuf) | ``enu -> ned`` (fixed: the 3D view is upright), ``ned -> body`` per estimate, ``ned -> truth_body`` / ``ned -> reference_body`` 1 m east |
| ``/pose``, ``/truth/pose``, ``/reference/pose`` | ``foxglove.PoseInFrame`` (protobuf) | estimate (at the origin of ``ned``), simulator truth and the autopilot's attitude (1 m east) |
| ``/estimate`` | ``bingham_fuser.Estimate`` (JSON) | the full estimate, as recorded and published on zenoh |
| ``/uncertainty`` | ``bingham_fuser.Uncertainty`` (JSON) | RMS angle, the 3x3 orientation covariance about north, east, down and its per-axis sigmas |
| ``/input/imu`` ... | as in the MCAP log (JSON) | every input sample |
| ``/status`` | ``bingham_fuser.Status`` (JSON) | health and counters, once a second |

The same frame tree goes into recordings (``/tf`` in :mod:`fuser.record`). Message log times
are the loop's times (``t_ns``, the sample's receive time). A channel nobody subscribes to costs
almost nothing: messages are built only when some client listens. Never raises into the loop:
failures are counted in ``errors``, the first logged once.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from drivers.samples import AttitudeSample, Quat, Sample
from fuser.codec import Estimate, dumps, encode_sample, sample_channel
from fuser.frames import BODY_FRAME, TRUTH_OFFSET_NED_M, WORLD_FRAME, body_transforms, orientation_covariance_ned
from fuser.record import CHANNELS, INPUT_TOPICS, TRUTH_FRAME

__all__ = ["DEFAULT_PORT", "REFERENCE_FRAME", "UNCERTAINTY", "FoxgloveLive"]

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""
REFERENCE_FRAME = "reference_body"
"""The autopilot's attitude (AttitudeSample inputs) as a body frame of its own."""

_NUM = {"type": "number"}
UNCERTAINTY = {
    "title": "bingham_fuser.Uncertainty",
    "description": "uncertainty of one estimate",
    "type": "object",
    "properties": {
        "t_ns": {"type": "integer", "description": "tick time, ns"},
        "rms_deg": {**_NUM, "description": "RMS angle between the estimate and the truth under the posterior, degrees"},
        "sigma_ned_deg": {"type": "array", "items": _NUM, "minItems": 3, "maxItems": 3,
                          "description": "one-sigma rotation error about north, east, down, degrees"},
        "covariance_ned_rad2": {"type": "array", "items": _NUM, "minItems": 9, "maxItems": 9,
                                "description": "3x3 covariance of the world-frame error rotation (NED axes), row-major, rad^2"},
    },
    "required": ["t_ns", "rms_deg", "sigma_ned_deg", "covariance_ned_rad2"],
}


def _missing() -> ImportError:
    return ImportError("--foxglove needs the 'foxglove-sdk' package: pip install 'bingham-fuser[foxglove]'")


class FoxgloveLive:
    """A Foxglove WebSocket server fed by the pipeline's sinks; ``close()`` stops it."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "bingham-fuser") -> None:
        try:
            import foxglove
            from foxglove import channels, messages
        except ImportError as exc:
            raise _missing() from exc
        self._m = messages
        self.errors = 0
        self.error: str | None = None
        self.published = 0
        self._context = foxglove.Context()
        ctx = self._context
        self._tf = channels.FrameTransformsChannel("/tf", context=ctx)
        self._poses = {topic: channels.PoseInFrameChannel(topic, context=ctx) for topic in ("/pose", "/truth/pose", "/reference/pose")}
        self._json = {
            topic: foxglove.Channel(topic, schema=schema, message_encoding="json", context=ctx)
            for topic, schema in [("/estimate", CHANNELS["/estimate"]), ("/uncertainty", UNCERTAINTY), ("/status", CHANNELS["/status"]),
                                  *((t, CHANNELS[t]) for t in INPUT_TOPICS)]
        }
        self._server: Any = None
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=ctx)
        except Exception as e:  # noqa: BLE001 - e.g. the port is taken: the fuser goes on without a live view
            self._fail(f"cannot serve on {host}:{port}, no live view: {e}")

    @property
    def port(self) -> int | None:
        """The port actually bound (useful with port 0), or None if the server did not start."""
        return None if self._server is None else self._server.port

    def subscribed_topics(self) -> list[str]:
        """Topics some client subscribes to now (for the status)."""
        channels = [self._tf, *self._poses.values(), *self._json.values()]
        return sorted(c.topic() for c in channels if c.has_sinks())

    def _fail(self, message: str) -> None:
        self.errors += 1
        if self.error is None:
            self.error = message
            log.error("foxglove: %s", message)

    def _log(self, channel: Any, message: Any, log_time: int) -> None:
        try:
            channel.log(message, log_time=log_time)
            self.published += 1
        except Exception as e:  # noqa: BLE001 - keep the loop going whatever the SDK does
            self._fail(f"logging on {channel.topic()} failed: {e}")

    def _body(self, t_ns: int, frame: str, q_wxyz: Quat, pose_topic: str, offset: tuple[float, float, float]) -> None:
        m = self._m
        stamp = m.Timestamp(*divmod(t_ns, 1_000_000_000))
        if self._tf.has_sinks():
            transforms = [m.FrameTransform(timestamp=stamp, parent_frame_id=parent, child_frame_id=child,
                                           translation=m.Vector3(x=t[0], y=t[1], z=t[2]), rotation=m.Quaternion(x=r[0], y=r[1], z=r[2], w=r[3]))
                          for parent, child, t, r in body_transforms(frame, q_wxyz, offset)]
            self._log(self._tf, m.FrameTransforms(transforms=transforms), t_ns)
        pose = self._poses[pose_topic]
        if pose.has_sinks():
            w, x, y, z = (float(c) for c in q_wxyz)
            msg = m.PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME,
                                pose=m.Pose(position=m.Vector3(x=offset[0], y=offset[1], z=offset[2]),
                                            orientation=m.Quaternion(x=x, y=y, z=z, w=w)))
            self._log(pose, msg, t_ns)

    # -- sinks ------------------------------------------------------------------
    def write_estimate(self, est: Estimate) -> None:
        """An EstimateSink: ``/tf``, ``/pose``, ``/estimate``, ``/uncertainty``."""
        if self._server is None:
            self.errors += 1
            return
        self._body(est.t_ns, BODY_FRAME, est.q_wxyz, "/pose", (0.0, 0.0, 0.0))
        if self._json["/estimate"].has_sinks():
            self._log(self._json["/estimate"], est.to_json(), est.t_ns)
        if self._json["/uncertainty"].has_sinks():
            try:
                cov = orientation_covariance_ned(est.M, est.Z, est.q_wxyz)
            except ValueError as e:
                self._fail(f"no covariance for the estimate at t_ns={est.t_ns}: {e}")
                return
            sigma = [math.degrees(math.sqrt(max(v, 0.0))) for v in np.diag(cov)]
            msg = {"t_ns": est.t_ns, "rms_deg": est.uncertainty_deg, "sigma_ned_deg": sigma, "covariance_ned_rad2": cov.reshape(9).tolist()}
            self._log(self._json["/uncertainty"], dumps(msg), est.t_ns)

    def write_sample(self, sample: Sample, receive_ns: int) -> None:
        """An InputSink: ``/input/...``; an autopilot's attitude also as ``/reference/pose`` and its body frame."""
        if self._server is None:
            return
        channel = self._json[sample_channel(sample)]
        if channel.has_sinks():
            self._log(channel, dumps(encode_sample(sample, receive_ns)), receive_ns)
        if isinstance(sample, AttitudeSample):
            self._body(receive_ns, REFERENCE_FRAME, sample.q_wxyz, "/reference/pose", TRUTH_OFFSET_NED_M)

    def write_truth(self, t_ns: int, q_wxyz: Quat, log_time_ns: int | None = None) -> None:
        """A truth sink (the simulator): ``/truth/pose`` and the ``truth_body`` frame 1 m east, on the
        run's timeline (``log_time_ns``, the estimates' clock; ``t_ns`` is the vehicle's own)."""
        if self._server is not None:
            self._body(t_ns if log_time_ns is None else log_time_ns, TRUTH_FRAME, q_wxyz, "/truth/pose", TRUTH_OFFSET_NED_M)

    def write_status(self, t_ns: int, status: dict[str, Any]) -> None:
        """A status sink: ``/status``."""
        if self._server is not None and self._json["/status"].has_sinks():
            self._log(self._json["/status"], dumps(status), t_ns)

    def close(self) -> None:
        if self._server is not None:
            server, self._server = self._server, None
            try:
                server.stop()
            except Exception as e:  # noqa: BLE001
                self._fail(f"stop failed: {e}")
