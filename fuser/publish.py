"""zenoh publishing of estimates and status, and the matching subscriber side.

Keys: ``bingham_fuser/<vehicle>/attitude`` (one :class:`~fuser.codec.Estimate`
as JSON per tick) and ``bingham_fuser/<vehicle>/status`` (a JSON dict). Once
open, the publisher never raises: a zenoh failure is logged once and counted,
and the fusion loop goes on. Opening is where a mistake shows:
:meth:`ZenohPublisher.open` raises :class:`ZenohOpenError` (a listen port in
use, a malformed endpoint), so that a command fails at start with one clear
line instead of running without output. See ``fuser/IO.md`` for the payloads
and endpoints.
"""

from __future__ import annotations

import json
import logging
import queue
import re
import sys
import threading
from collections import Counter
from collections.abc import Callable
from typing import Any, TextIO

import zenoh

from .codec import Estimate, MalformedPayload, dumps
from .errors import EXIT_USAGE, FuserError
from .streams import let_go

__all__ = [
    "DEFAULT_ENDPOINT",
    "Subscription",
    "ZenohOpenError",
    "ZenohPublisher",
    "format_estimate",
    "key",
    "listen",
    "open_session",
    "subscribe",
    "zenoh_config",
]

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def key(vehicle: str, leaf: str) -> str:
    """``bingham_fuser/<vehicle>/<leaf>``; vehicle ``*`` matches every vehicle when subscribing."""
    return f"bingham_fuser/{vehicle}/{leaf}"


def check_vehicle(vehicle: str, listening: bool = False) -> None:
    """A ValueError unless ``vehicle`` is one chunk of a zenoh key expression without wildcards (``*`` alone too
    when ``listening``: every vehicle). An empty name, a ``/``, ``#``, ``?`` or ``$`` made every put fail (the run went
    on publishing nothing), and a ``*`` would publish one vehicle's estimates as every vehicle's."""
    if listening and vehicle == "*":
        return
    problem = "it is empty" if not vehicle else "it holds a '/' or a '*'" if {"/", "*"} & set(vehicle) else None
    if problem is None:
        try:
            zenoh.KeyExpr(key(vehicle, "attitude"))
        except zenoh.ZError as e:  # the message ends with the location in zenoh's sources
            problem = str(e).split(" at /")[0]
    if problem is not None:
        raise ValueError(f"fuser.vehicle {vehicle!r} is not a name for the zenoh keys bingham_fuser/<vehicle>/...: {problem}")


class ZenohOpenError(FuserError):
    """A zenoh session could not be opened.

    ``endpoint_in_use`` is the listen endpoint that another process holds (a
    second fuser, or a zenoh router such as ROS 2's rmw_zenoh on 7447), if
    that was the reason; ``malformed`` is True when an endpoint could not be
    parsed (a usage error).
    """

    def __init__(self, reason: str, endpoint_in_use: str | None = None, malformed: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.endpoint_in_use = endpoint_in_use
        self.malformed = malformed
        if malformed:
            self.exit_code = EXIT_USAGE

    @classmethod
    def from_zerror(cls, error: zenoh.ZError) -> ZenohOpenError:
        reason = re.sub(r" at /\S+\.rs:\d+\.?", "", str(error))  # zenoh appends its Rust source location
        in_use = re.search(r"bound to (\S+?): .*(?:in use|os error 98)", reason)
        malformed = bool(re.search(r"must be of the form|invalid socket address|invalid port", reason))
        return cls(reason, in_use.group(1) if in_use else None, malformed)


def zenoh_config(listen: list[str] | None = None, connect: list[str] | None = None) -> zenoh.Config:
    """A peer configuration with explicit endpoints and multicast/gossip scouting off.

    With neither argument the peer listens on ``tcp/127.0.0.1:7447``; with only
    ``connect`` it listens nowhere (it dials out, e.g. to a router). A
    malformed endpoint raises :class:`ZenohOpenError`.
    """
    if listen is None:
        listen = [] if connect else [DEFAULT_ENDPOINT]
    conf = {
        "mode": "peer",
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": list(connect or [])},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }
    try:
        return zenoh.Config.from_json5(json.dumps(conf))
    except zenoh.ZError as e:
        raise ZenohOpenError.from_zerror(e) from e


def open_session(config: zenoh.Config) -> zenoh.Session:
    """``zenoh.open``, raising :class:`ZenohOpenError` with the reason (and the endpoint in use, if that was it)."""
    try:
        return zenoh.open(config)
    except zenoh.ZError as e:
        raise ZenohOpenError.from_zerror(e) from e


class ZenohPublisher:
    """Publish estimates and status for one vehicle; counts failures in ``errors``, never raises.

    Puts use congestion control DROP and express delivery: a slow subscriber
    loses samples rather than stalling the loop, and nothing waits for a batch.
    """

    def __init__(self, config: zenoh.Config, vehicle: str, session: zenoh.Session | None = None) -> None:
        """Open a session on ``config`` (or use ``session``); a session that cannot open is logged and counted."""
        self.vehicle = vehicle
        self.published = 0
        self.errors = 0
        self.error: str | None = None
        """The first failure, for the status."""
        self._session: zenoh.Session | None = None
        self._attitude: zenoh.Publisher | None = None
        self._status: zenoh.Publisher | None = None
        try:
            self._session = zenoh.open(config) if session is None else session
            self._attitude = self._declare(self._session, "attitude")
            self._status = self._declare(self._session, "status")
        except zenoh.ZError as e:
            self._fail(f"cannot open the zenoh session, nothing will be published: {e}")

    @classmethod
    def open(cls, config: zenoh.Config, vehicle: str) -> ZenohPublisher:
        """A publisher whose session is open: raises :class:`ZenohOpenError` instead of publishing nothing."""
        return cls(config, vehicle, open_session(config))

    def _declare(self, session: zenoh.Session, leaf: str) -> zenoh.Publisher:
        return session.declare_publisher(
            key(self.vehicle, leaf),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.DROP,
            express=True,
        )

    def _fail(self, message: str) -> None:
        self.errors += 1
        if self.error is None:
            self.error = message
            log.error("zenoh: %s", message)

    def _put(self, publisher: zenoh.Publisher | None, payload: bytes | None) -> None:
        if payload is None:
            return
        if publisher is None:
            self.errors += 1
            return
        try:
            publisher.put(payload)
            self.published += 1
        except zenoh.ZError as e:
            self._fail(f"put failed: {e}")

    @property
    def has_subscribers(self) -> bool:
        """True when some subscriber matches the attitude key."""
        try:
            return self._attitude is not None and self._attitude.matching_status.matching
        except zenoh.ZError:
            return False

    def publish_estimate(self, est: Estimate) -> None:
        self._put(self._attitude, self._encode(est.to_dict()))

    def publish_status(self, status: dict[str, Any]) -> None:
        self._put(self._status, self._encode(status))

    def _encode(self, payload: Any) -> bytes | None:
        try:
            return dumps(payload)
        except (TypeError, ValueError) as e:  # NaN or infinity: JSON has no form for them
            self._fail(f"cannot encode a payload as JSON: {e}")
            return None

    def close(self) -> None:
        if self._session is not None:
            session, self._session = self._session, None
            self._attitude = self._status = None
            try:
                session.close()
            except zenoh.ZError as e:
                self._fail(f"close failed: {e}")


class Subscription:
    """Callbacks on raw payloads of ``bingham_fuser/<vehicle>/<leaf>``, each called with the publishing vehicle's
    name (``vehicle`` may be ``*``) and the payload; ``close()`` to stop. Anyone on the network can put on those
    keys: a handler that finds a payload is not what the key carries raises :class:`MalformedPayload`, and the
    payload is counted in :attr:`ignored` by that reason, never passed on."""

    def __init__(self, config: zenoh.Config, vehicle: str, handlers: dict[str, Callable[[str, bytes], None]]) -> None:
        self.ignored: Counter[str] = Counter()
        """Payloads the handlers refused, by ``<leaf>: <reason>`` (a fixed set of reasons: bounded)."""
        self._counting = threading.Lock()
        """zenoh may call the handlers from more than one thread."""
        self._session = open_session(config)
        self._subscribers = [
            self._session.declare_subscriber(key(vehicle, leaf), self._on_payload(leaf, handler)) for leaf, handler in handlers.items()
        ]

    def _on_payload(self, leaf: str, handler: Callable[[str, bytes], None]) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            try:
                handler(str(sample.key_expr).split("/")[1], sample.payload.to_bytes())  # bingham_fuser/<vehicle>/<leaf>
            except MalformedPayload as exc:
                with self._counting:
                    self.ignored[f"{leaf}: {exc}"] += 1
        return on_sample

    def close(self) -> None:
        self._session.close()

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def subscribe(
    config: zenoh.Config,
    vehicle: str,
    on_estimate: Callable[[Estimate], None],
    on_status: Callable[[dict[str, Any]], None] | None = None,
) -> Subscription:
    """Call ``on_estimate`` (and ``on_status``) from zenoh's thread for each arriving message; a payload that is not
    an estimate (or a status that is not a JSON object) is counted in the subscription's ``ignored``."""
    handlers = {"attitude": lambda _, b: on_estimate(Estimate.from_json(b))}
    if on_status is not None:
        handlers["status"] = lambda _, b: on_status(_status(b))
    return Subscription(config, vehicle, handlers)


def _status(payload: bytes) -> dict[str, Any]:
    """A status payload's object (fuser/IO.md); :class:`MalformedPayload` if it is not a JSON object."""
    try:
        status = json.loads(payload)
    except (ValueError, RecursionError):
        status = None
    if not isinstance(status, dict):
        raise MalformedPayload("not a JSON object")
    return status


def format_estimate(est: Estimate) -> str:
    """One human line: its time, roll/pitch/yaw and uncertainty in degrees, and which kind it is (a tick's, or the
    output predictor's between ticks)."""
    roll, pitch, yaw = est.euler_deg
    return (
        f"t={est.t_ns / 1e9:12.6f} s  roll={roll:8.3f}  pitch={pitch:8.3f}  yaw={yaw:8.3f} deg"
        f"  +/-{est.uncertainty_deg:.3f} deg  {'predicted' if est.predicted else 'tick'}"
    )


MAX_WAITING = 10_000
"""Estimates ``listen`` holds for printing; beyond, new ones are dropped and counted (a terminal slower than a
fleet's estimates: memory stays bounded)."""
POLL_S = 0.5
"""How often ``listen`` looks for ignored payloads to tell of while no estimate arrives (s)."""


def listen(
    config: zenoh.Config, vehicle: str, json_output: bool = False, count: int | None = None, out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
) -> int:
    """Print arriving estimates, one line each (raw JSON with ``json_output``), until ``count`` or Ctrl-C; listening
    to every vehicle (``*``), each human line begins with the vehicle's name.

    A payload that is not an estimate (anyone can put on the key) is not printed: the first one is said on ``err``
    with its reason, and at the end how many were ignored, by reason, and how many were dropped because printing
    fell behind. Returns how many were printed.
    """
    arrived: queue.Queue[tuple[str, Estimate, bytes]] = queue.Queue(MAX_WAITING)
    dropped = 0
    dropping = threading.Lock()

    def on_attitude(name: str, payload: bytes) -> None:
        nonlocal dropped
        estimate = Estimate.from_json(payload)  # MalformedPayload: counted by the subscription
        try:
            arrived.put_nowait((name, estimate, payload))
        except queue.Full:
            with dropping:  # zenoh may call from more than one thread
                dropped += 1

    printed = 0
    with Subscription(config, vehicle, {"attitude": on_attitude}) as subscription:
        told = False
        try:
            while count is None or printed < count:
                if not told and subscription.ignored:
                    told = True
                    reason = next(iter(dict(subscription.ignored))).removeprefix("attitude: ")  # a copy: counted meanwhile
                    print(f"listen: ignored a payload on {key(vehicle, 'attitude')} that is not an estimate ({reason}); "
                          "further ones are counted", file=err, flush=True)
                try:
                    name, estimate, payload = arrived.get(timeout=POLL_S)
                except queue.Empty:
                    continue
                line = payload.decode() if json_output else format_estimate(estimate)
                if "*" in vehicle and not json_output:
                    line = f"{name}: {line}"
                try:
                    print(line, file=out, flush=True)
                except BrokenPipeError:  # its reader stopped (listen | head): the end, as --count's
                    let_go(out)
                    break
                printed += 1
        except KeyboardInterrupt:
            pass
        ignored = dict(subscription.ignored)
    if ignored or dropped:
        what = [f"ignored {sum(ignored.values())} payloads that are not estimates ("
                + ", ".join(f"{k.removeprefix('attitude: ')}: {v}" for k, v in sorted(ignored.items())) + ")"] if ignored else []
        what += [f"dropped {dropped} estimates while printing fell behind"] if dropped else []
        print("listen: " + "; ".join(what), file=err, flush=True)
    return printed
