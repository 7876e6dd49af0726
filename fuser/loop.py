"""The fixed-rate fusion loop: buffers samples by time and emits one estimate per tick.

The loop is a pure function of its inputs, ``(sample, receive_ns)`` pairs in
arrival order: live and replay share every line of it, and replaying a log
gives the same estimates byte for byte.

Timeline. Each sender stamps samples with its own clock. For every stream
(source and sample type; an autopilot's GNSS solution and its receiver's fix
are two) the loop keeps ``offset = min(receive_ns - t_ns)``, the smallest
latency seen, and places a sample at ``t_ns + offset``: the sender's precise
spacing, anchored to the receiver's clock. Tick ``T`` (on a grid of
``1/rate``) fuses the samples placed in ``(T - period, T]`` and runs once the
clock reaches ``T + wait``; a sample placed at or before a tick that already
ran is late, counted and dropped.

The wait. A sample's *lateness* is ``receive_ns - placed``: zero for the
fastest sample of its stream, the link's jitter for the others (20-150 ms
over a telemetry radio, well under a millisecond on a wire). With
``[fuser.latency] adaptive`` (the default) the wait is the largest, over the
streams heard within ``window_s``, of each stream's ``quantile`` of lateness
over that window, never less than ``fuser.latency_ms`` nor more than
``max_ms`` (:class:`Timeline`): a wired link keeps its few milliseconds, a radio
gets what its jitter needs. It is measured again once a second of the
receive timeline (between ticks, so that no estimate waits for it), raised at
once by a sample later than it (a link that slows down), and starts at the
cap until a stream has shown its lateness (``_MIN_SAMPLES`` samples), so the
first seconds of a slow link are not lost either. It comes down by at most
half a tick period per tick: the ticks it held back run at up to twice the
rate, not in one burst. It is a function of the
inputs only, so a replay reproduces it. Because the offset only ever
decreases, samples held up at start-up (a stall under load) are placed late
and counted as late against the first offset, never the later ones: the
next faster sample lowers the offset, and the stall's lateness leaves the
window after ``window_s``.

The loop is the one owner of this timeline: it hands the model each tick's
samples with their placed times (:class:`fuser.model.TickInput`), and picks
the reference IMU (the first IMU stream to arrive), whose clock the
estimates' ``sensor_t_ns`` is on.

One vehicle. On each transport the first IMU's vehicle (:func:`vehicle_of`)
is the one fused: its IMUs (ArduPilot's RAW_IMU, SCALED_IMU2, SCALED_IMU3 are
instances 0, 1, 2, each on its own clock) are fused together, and IMU,
attitude or GNSS samples of any other vehicle on that transport (another
MAVLink system id) are counted (``other_vehicle``) and dropped, never
averaged with it. A CAN bus and a MAVLink link given together are the one aircraft's (its
DroneCAN sensors and its autopilot): both are fused. The model returns a plain
:class:`fuser.model.TickResult`; the wire :class:`~fuser.codec.Estimate` is
built here from it (:func:`estimate_of`).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right, insort
from collections import Counter, deque
from typing import Any, Mapping

from core.bingham import Bingham
from drivers.euler import euler_from_quaternion
from drivers.samples import AttitudeSample, GnssSample, ImuSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.config import FuserConfig, LatencySettings
from fuser.model import FusionModel, TickInput, TickResult
from fuser.model.extrapolation import ahead_ns
from fuser.model.output import OutputPredictor

__all__ = ["FusionLoop", "Timeline", "estimate_of", "stream_of", "vehicle_of"]


def vehicle_of(source: SourceId) -> tuple:
    """The vehicle a sample comes from: its MAVLink system id (any component, any instance); on a CAN bus
    every node is part of the one vehicle."""
    return (source.transport,) if source.transport == "dronecan" else (source.transport, source.system)


def stream_of(sample: Sample) -> tuple:
    """The stream a sample belongs to, each with its own clock offset: source and sample type, and for GNSS
    whether it is an autopilot's solution (GLOBAL_POSITION_INT, boot clock) or a receiver's fix (GPS_RAW_INT,
    often Unix time) from the same source."""
    if isinstance(sample, GnssSample):
        return (sample.source, GnssSample, sample.filtered)
    return (sample.source, type(sample))


_Pending = tuple[int, int, Sample]
"""A buffered sample: (placed_ns, arrival number, sample); the arrival number keeps the order total."""

_MIN_SAMPLES = 30
"""A stream's lateness is known once this many of its samples lie in the window; until then it asks for the cap."""
_MAX_KEPT = 4096
"""Most samples kept per stream for the quantile (10 s of a 400 Hz IMU)."""
_MEASURE_EVERY_NS = 1_000_000_000
"""The wait is measured again once per second of the receive timeline."""


class _Lateness:
    """One stream's recent ``receive_ns - t_ns``, in arrival order (to expire) and sorted (for the quantile)."""

    __slots__ = ("arrivals", "sorted")

    def __init__(self) -> None:
        self.arrivals: deque[tuple[int, int]] = deque()
        self.sorted: list[int] = []

    def add(self, receive_ns: int, latency_ns: int, window_ns: int) -> None:
        self.arrivals.append((receive_ns, latency_ns))
        insort(self.sorted, latency_ns)
        self.expire(receive_ns - window_ns)
        if len(self.arrivals) > _MAX_KEPT:
            self._drop_oldest()

    def expire(self, before_ns: int) -> None:
        """Forget the samples received before ``before_ns``."""
        while self.arrivals and self.arrivals[0][0] < before_ns:
            self._drop_oldest()

    def _drop_oldest(self) -> None:
        _, latency = self.arrivals.popleft()
        del self.sorted[bisect_left(self.sorted, latency)]

    def quantile(self, q: float) -> int:
        """The ``q`` quantile (the higher of two neighbours): the sample ``ceil(q (n - 1))`` in sorted order."""
        return self.sorted[math.ceil(q * (len(self.sorted) - 1))]


class Timeline:
    """Each stream's clock offset (where its samples are placed) and the wait its lateness asks for.

    :meth:`place` puts a sample on the loop's timeline; :attr:`wait_ns` is how long a tick waits for samples
    in flight (module docstring), between ``floor_ns`` and ``cap_ns``. Deterministic in what it is given; a
    sample costs a sorted insertion (microseconds), the measurement once a second a look-up per stream.
    """

    def __init__(self, params: LatencySettings, floor_ms: float) -> None:
        self.params = params
        self.floor_ns = round(floor_ms * 1e6)
        self.cap_ns = max(self.floor_ns, round(params.max_ms * 1e6))
        self.window_ns = round(params.window_s * 1e9)
        self.wait_ns = self.cap_ns if params.adaptive else self.floor_ns
        """The wait the lateness asks for."""
        self.offsets: dict[tuple, int] = {}
        """Per stream, in order of first arrival: the smallest receive - send time."""
        self._latency: dict[tuple, _Lateness] = {}
        """Per stream: its samples within the window."""
        self._next_measure_ns: int | None = None

    def place(self, stream: tuple, t_ns: int, receive_ns: int) -> int:
        """The time on the loop's timeline of a sample of ``stream`` stamped ``t_ns``, received at ``receive_ns``."""
        latency = receive_ns - t_ns
        offset = self.offsets[stream] = min(latency, self.offsets.get(stream, latency))
        if self.params.adaptive:
            kept = self._latency.get(stream)
            if kept is None:
                kept = self._latency[stream] = _Lateness()
            kept.add(receive_ns, latency, self.window_ns)
            if self._next_measure_ns is None or receive_ns >= self._next_measure_ns:
                self._next_measure_ns = receive_ns + _MEASURE_EVERY_NS
                self.wait_ns = self._measured(receive_ns)
            if latency - offset > self.wait_ns:  # a link slowing down: wait longer from now on
                self.wait_ns = min(self.cap_ns, latency - offset)
        return t_ns + offset

    def _measured(self, now_ns: int) -> int:
        """The largest of every recent stream's lateness quantile, within the floor and the cap."""
        wait = self.floor_ns
        for stream, kept in list(self._latency.items()):
            kept.expire(now_ns - self.window_ns)
            if not kept.arrivals:
                del self._latency[stream]
                continue
            if len(kept.arrivals) < _MIN_SAMPLES:
                return self.cap_ns
            wait = max(wait, kept.quantile(self.params.quantile) - self.offsets[stream])
        return min(wait, self.cap_ns)


class FusionLoop:
    """Ticks at ``config.rate_hz`` on the time the caller gives it (wall clock live, log time in replay)."""

    def __init__(self, config: FuserConfig, max_catch_up_ticks: int | None = None) -> None:
        self.config = config
        self.model = FusionModel(config)
        self.period_ns = round(1e9 / config.rate_hz)
        self.timeline = Timeline(config.latency, config.latency_ms)
        """Each stream's clock offset and the wait for samples in flight."""
        self._wait_ns = self.timeline.wait_ns
        """The wait the last tick ran under: up at once to the timeline's, down by at most half a period per tick
        (the ticks it held back then run at up to twice the rate, each on time for the wait it ran under)."""
        self.max_catch_up_ticks = max_catch_up_ticks
        self.counters: Counter[str] = Counter()
        self._pending: list[_Pending] = []
        self._seq = 0
        self._next_tick: int | None = None
        self._last_tick: int | None = None
        self.reference_imu: SourceId | None = None
        """The first IMU stream to arrive: the estimates' ``sensor_t_ns`` is on its clock."""
        self._vehicles: dict[str, tuple] = {}
        """Per transport, the vehicle fused: the one of its first IMU sample."""
        self._latest_diagnostics: dict[str, dict[str, Any]] = {}
        self._ahead_ns = ahead_ns(config)
        self._output: OutputPredictor | None = self.model.output_predictor() if config.extrapolation.every_imu_sample else None
        """The output predictor (``extrapolation.every_imu_sample``; None: off), active from a tick to the next."""
        self._last_result: TickResult | None = None
        self._last_counters: dict[str, int] = {}
        self._last_stamp_ns = -(2**63)
        """The last estimate's stamp: with the output predictor every stamp is after it. A tick is due at its own time
        and never held back (a tick held until after the last prediction starved every tick whose samples arrived
        at its due instant); one due at or before a prediction's stamp (the wait came down at that sample,
        :meth:`Timeline.place`) is stamped 1 ns after it, and a prediction at an instant a tick's estimate already
        has is not published (``fuser/IO.md``)."""

    @property
    def latency_ns(self) -> int:
        """How long the last tick waited after its time for samples in flight (:class:`Timeline`)."""
        return self._wait_ns

    def due_ns(self, estimate: Estimate) -> int:
        """The clock time the tick that made ``estimate`` was due: its tick time (the estimate is stamped
        ``ahead_ns`` after it, :mod:`fuser.model.extrapolation`) plus the wait it ran under. For ticks run
        together to catch up, the last one's wait (the smallest): never later than the tick's real due time. With
        ``extrapolation.every_imu_sample`` every estimate is stamped when it is due: a tick's at its due time, the
        output predictor's at its sample's arrival."""
        if self.config.extrapolation.every_imu_sample:
            return estimate.t_ns
        return estimate.t_ns - self._ahead_ns + self._wait_ns

    @property
    def next_due_ns(self) -> int | None:
        """Clock time at which the next tick will run, or None before the first sample."""
        return None if self._next_tick is None else self._next_tick + self._next_wait_ns()

    def _next_wait_ns(self) -> int:
        """The wait of the next tick: the timeline's, or half a period less than the last tick's if that is more."""
        return max(self.timeline.wait_ns, self._wait_ns - self.period_ns // 2)

    def push(self, sample: Sample, receive_ns: int) -> list[Estimate]:
        """Hand a sample to the loop; it is fused by the tick that covers its time. With
        ``extrapolation.every_imu_sample``, a sample of the reference IMU returns the output predictor's estimate
        at its arrival (:mod:`fuser.model.output`); otherwise nothing."""
        if isinstance(sample, (ImuSample, AttitudeSample, GnssSample)):
            vehicle = vehicle_of(sample.source)
            if isinstance(sample, ImuSample):
                chosen = self._vehicles.setdefault(sample.source.transport, vehicle)
                if self.reference_imu is None:
                    self.reference_imu = sample.source
            else:
                chosen = self._vehicles.get(sample.source.transport, vehicle)
            if vehicle != chosen:
                self.counters["other_vehicle"] += 1
                return []
        placed = self.timeline.place(stream_of(sample), sample.t_ns, receive_ns)
        if self._last_tick is not None and placed <= self._last_tick:
            self.counters["late"] += 1
            return []
        if self._next_tick is None:
            self._next_tick = -(-placed // self.period_ns) * self.period_ns  # first grid point at or after it
        self._pending.append((placed, self._seq, sample))
        self._seq += 1
        self.counters["samples"] += 1
        if self._predicted_through(sample, placed) and self._last_result is not None and receive_ns > self._last_stamp_ns:
            # none where a tick's estimate already has this instant (due just as the sample arrived): stamps only go forward
            return [self._estimate(receive_ns, *self._output.at(receive_ns), self._last_result, (), predicted=True)]  # type: ignore[union-attr]
        return []

    def _predicted_through(self, sample: Sample, placed_ns: int) -> bool:
        """Turn the output predictor through ``sample`` if it turns it (:meth:`_turns_prediction`); True if it is the
        reference IMU's and the prediction now ends there."""
        if self._output is None or not self._turns_prediction(sample, self._output):
            return False
        ended = self._output.advance(sample.gyro_rad_s, placed_ns)  # False if the prediction has stopped
        return ended and sample.source == self.reference_imu

    def _turns_prediction(self, sample: Sample, output: OutputPredictor) -> bool:
        """The reference IMU's samples turn the output predictor, and in a slow gyro stream (``output.slow``: a
        telemetry link's IMUs at a few hertz each) the vehicle's other IMUs' too: the tick merges them into one
        stream, and between the reference's samples they are the only rate there is (``fuser/model/output.py``).
        ``slow`` is read last: a field of the compiled predictor's record, it costs more than the rest per sample."""
        return isinstance(sample, ImuSample) and (sample.source == self.reference_imu or output.slow)

    def advance(self, now_ns: int) -> list[Estimate]:
        """Run every tick whose due time (tick + latency) is at or before ``now_ns``."""
        out: list[Estimate] = []
        while self._next_tick is not None and self._next_tick + (wait := self._next_wait_ns()) <= now_ns:
            self._wait_ns = wait
            behind = (now_ns - wait - self._next_tick) // self.period_ns
            if self.max_catch_up_ticks is not None and behind > self.max_catch_up_ticks:
                skip_to = now_ns - wait - self.max_catch_up_ticks * self.period_ns
                skipped = (skip_to - self._next_tick) // self.period_ns
                self.counters["ticks_skipped"] += skipped
                self._next_tick += skipped * self.period_ns
            out.append(self._tick(self._next_tick))
            self._next_tick += self.period_ns
        return out

    def flush(self) -> list[Estimate]:
        """Run the ticks that cover every sample still pending (end of a log), up to the one that covers the last:
        none skipped (the samples arrived within the wait: no gap, however many periods it is) and none after it
        (each tick lets the wait down by half a period: a flush to the last sample's due time ran on past it)."""
        if not self._pending:
            return []
        last_ns = max(p[0] for p in self._pending)
        out: list[Estimate] = []
        while self._next_tick is not None and self._next_tick - self.period_ns < last_ns:  # the tick covering it is the first at or after it
            self._wait_ns = self._next_wait_ns()
            out.append(self._tick(self._next_tick))
            self._next_tick += self.period_ns
        return out

    def diagnostics(self) -> dict[str, dict[str, Any]]:
        """The latest diagnostic of each measurement update (with its tick time ``t_ns``), for the status."""
        return dict(self._latest_diagnostics)

    def _tick(self, tick_ns: int) -> Estimate:
        self._pending.sort()
        split = bisect_right(self._pending, (tick_ns, math.inf))  # every sample placed at or before the tick
        due, self._pending = self._pending[:split], self._pending[split:]
        dt = self.period_ns if self._last_tick is None else tick_ns - self._last_tick
        self._last_tick = tick_ns
        self.counters["ticks"] += 1
        result = self.model.step(TickInput(tick_ns, dt, [p[2] for p in due], [p[0] for p in due]))
        self._last_result, self._last_counters = result, {**result.counters, **self.counters}
        output = self._output
        if output is not None:  # extrapolation.every_imu_sample: the tick's state turned through the samples already here
            # stamped when due, or just after the last prediction's stamp if a sample received after that went first
            stamp, published, spread_deg = max(tick_ns + self._wait_ns, self._last_stamp_ns + 1), result.published, None
            self.model.start_output(output)
            output.advance_through([(sample.gyro_rad_s, placed) for placed, _, sample in self._pending if self._turns_prediction(sample, output)])
            if output.active:
                published, spread_deg = output.at(stamp)
        else:  # the time it is for (fuser.model.extrapolation)
            stamp, published, spread_deg = tick_ns + result.ahead_ns, result.published, None
        estimate = self._estimate(stamp, published, spread_deg, result, result.diagnostics)
        for d in estimate.diagnostics:
            self._latest_diagnostics[d["update"]] = {"t_ns": tick_ns, **d}
        return estimate

    def _estimate(self, stamp_ns: int, published: Bingham, spread_deg: float | None, result: TickResult, diagnostics: tuple,
                  predicted: bool = False) -> Estimate:
        """The wire estimate of ``published`` (the last tick's ``result``, or turned from it, and widened if
        ``spread_deg``, its RMS angle, is given) stamped ``stamp_ns``."""
        offset = None if self.reference_imu is None else self.timeline.offsets[(self.reference_imu, ImuSample)]
        # a right rotation keeps the tick's spread; a widened prediction has its own
        turned = TickResult(published, result.uncertainty_deg if spread_deg is None else spread_deg, diagnostics, result.counters)
        self._last_stamp_ns = stamp_ns
        return estimate_of(stamp_ns, turned, self._last_counters, None if offset is None else stamp_ns - offset, predicted)


def estimate_of(t_ns: int, result: TickResult, counters: Mapping[str, int], sensor_t_ns: int | None, predicted: bool = False) -> Estimate:
    """The wire estimate of one tick (or, ``predicted``, the output predictor's from it): the published distribution's
    mode, parameters and summaries."""
    state = result.published
    M = tuple(map(tuple, state.M.tolist()))
    w, x, y, z = M[0][3], M[1][3], M[2][3], M[3][3]  # the mode (Bingham.mode): M's last column, w >= 0
    q = (-w, -x, -y, -z) if w < 0 else (w, x, y, z)
    roll, pitch, yaw = euler_from_quaternion(q)
    return Estimate(
        t_ns=t_ns,
        q_wxyz=q,  # type: ignore[arg-type]
        M=M,  # type: ignore[arg-type]
        Z=tuple(state.Z.tolist()),  # type: ignore[arg-type]
        uncertainty_deg=result.uncertainty_deg,
        euler_deg=(math.degrees(roll), math.degrees(pitch), math.degrees(yaw)),
        counters=dict(counters),
        sensor_t_ns=sensor_t_ns,
        predicted=predicted,
        diagnostics=tuple([d.to_dict() for d in result.diagnostics]),
    )
