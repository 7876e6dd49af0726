"""The fixed-rate fusion loop: buffers samples by time and emits one estimate per tick.

The loop is a pure function of its inputs, ``(sample, receive_ns)`` pairs in
arrival order: live and replay share every line of it, and replaying a log
gives the same estimates byte for byte.

Timeline. Each sender stamps samples with its own clock. For every stream
(source and sample type) the loop keeps ``offset = min(receive_ns - t_ns)``,
the smallest latency seen, and places a sample at ``t_ns + offset``: the
sender's precise spacing, anchored to the receiver's clock. Tick ``T`` (on a
grid of ``1/rate``) fuses the samples placed in ``(T - period, T]`` and runs
once the clock reaches ``T + latency``; a sample placed at or before a tick
that already ran is late, counted and dropped.

The loop is the one owner of this timeline: it hands the model each tick's
samples with their placed times (:class:`fuser.model.TickInput`), and picks
the reference IMU (the first IMU stream to arrive), whose clock the
estimates' ``sensor_t_ns`` is on.

One vehicle. On each transport the first IMU's vehicle (:func:`vehicle_of`)
is the one fused: its IMUs (ArduPilot's RAW_IMU, SCALED_IMU2, SCALED_IMU3 are
instances 0, 1, 2, each on its own clock) are fused together, and IMU or
attitude samples of any other vehicle on that transport (another MAVLink
system id) are counted (``other_vehicle``) and dropped, never averaged with
it. A CAN bus and a MAVLink link given together are the one aircraft's (its
DroneCAN sensors and its autopilot): both are fused. The model returns a plain
:class:`fuser.model.TickResult`; the wire :class:`~fuser.codec.Estimate` is
built here from it (:func:`estimate_of`).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections import Counter
from typing import Any, Mapping

from drivers.euler import euler_from_quaternion
from drivers.samples import AttitudeSample, ImuSample, Sample, SourceId
from fuser.codec import Estimate
from fuser.config import FuserConfig
from fuser.model import FusionModel, TickInput, TickResult

__all__ = ["FusionLoop", "estimate_of", "vehicle_of"]


def vehicle_of(source: SourceId) -> tuple:
    """The vehicle a sample comes from: its MAVLink system id (any component, any instance); on a CAN bus
    every node is part of the one vehicle."""
    return (source.transport,) if source.transport == "dronecan" else (source.transport, source.system)


_Pending = tuple[int, int, Sample]
"""A buffered sample: (placed_ns, arrival number, sample); the arrival number keeps the order total."""


class FusionLoop:
    """Ticks at ``config.rate_hz`` on the time the caller gives it (wall clock live, log time in replay)."""

    def __init__(self, config: FuserConfig, max_catch_up_ticks: int | None = None) -> None:
        self.config = config
        self.model = FusionModel(config)
        self.period_ns = round(1e9 / config.rate_hz)
        self.latency_ns = round(config.latency_ms * 1e6)
        self.max_catch_up_ticks = max_catch_up_ticks
        self.counters: Counter[str] = Counter()
        self._offsets: dict[tuple, int] = {}
        """Per stream (source, sample type), in order of first arrival: the smallest receive - send time."""
        self._pending: list[_Pending] = []
        self._seq = 0
        self._next_tick: int | None = None
        self._last_tick: int | None = None
        self.reference_imu: SourceId | None = None
        """The first IMU stream to arrive: the estimates' ``sensor_t_ns`` is on its clock."""
        self._vehicles: dict[str, tuple] = {}
        """Per transport, the vehicle fused: the one of its first IMU sample."""
        self._latest_diagnostics: dict[str, dict[str, Any]] = {}

    @property
    def next_due_ns(self) -> int | None:
        """Clock time at which the next tick will run, or None before the first sample."""
        return None if self._next_tick is None else self._next_tick + self.latency_ns

    def push(self, sample: Sample, receive_ns: int) -> None:
        """Hand a sample to the loop; it is fused by the tick that covers its time."""
        if isinstance(sample, (ImuSample, AttitudeSample)):
            vehicle = vehicle_of(sample.source)
            if isinstance(sample, ImuSample):
                chosen = self._vehicles.setdefault(sample.source.transport, vehicle)
                if self.reference_imu is None:
                    self.reference_imu = sample.source
            else:
                chosen = self._vehicles.get(sample.source.transport, vehicle)
            if vehicle != chosen:
                self.counters["other_vehicle"] += 1
                return
        key = (sample.source, type(sample))
        offset = min(receive_ns - sample.t_ns, self._offsets.get(key, receive_ns - sample.t_ns))
        self._offsets[key] = offset
        placed = sample.t_ns + offset
        if self._last_tick is not None and placed <= self._last_tick:
            self.counters["late"] += 1
            return
        if self._next_tick is None:
            self._next_tick = -(-placed // self.period_ns) * self.period_ns  # first grid point at or after it
        self._pending.append((placed, self._seq, sample))
        self._seq += 1
        self.counters["samples"] += 1

    def advance(self, now_ns: int) -> list[Estimate]:
        """Run every tick whose due time (tick + latency) is at or before ``now_ns``."""
        out: list[Estimate] = []
        while self._next_tick is not None and self._next_tick + self.latency_ns <= now_ns:
            behind = (now_ns - self.latency_ns - self._next_tick) // self.period_ns
            if self.max_catch_up_ticks is not None and behind > self.max_catch_up_ticks:
                skip_to = now_ns - self.latency_ns - self.max_catch_up_ticks * self.period_ns
                skipped = (skip_to - self._next_tick) // self.period_ns
                self.counters["ticks_skipped"] += skipped
                self._next_tick += skipped * self.period_ns
            out.append(self._tick(self._next_tick))
            self._next_tick += self.period_ns
        return out

    def flush(self) -> list[Estimate]:
        """Run the ticks that cover every sample still pending (end of a log)."""
        if not self._pending:
            return []
        return self.advance(max(p[0] for p in self._pending) + self.period_ns + self.latency_ns - 1)

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
        offset = None if self.reference_imu is None else self._offsets[(self.reference_imu, ImuSample)]
        stamp = tick_ns + result.ahead_ns  # the time the published state is for (fuser.model.extrapolation)
        estimate = estimate_of(stamp, result, {**result.counters, **self.counters}, None if offset is None else stamp - offset)
        for d in estimate.diagnostics:
            self._latest_diagnostics[d["update"]] = {"t_ns": tick_ns, **d}
        return estimate


def estimate_of(t_ns: int, result: TickResult, counters: Mapping[str, int], sensor_t_ns: int | None) -> Estimate:
    """The wire estimate of one tick: the published distribution's mode, parameters and summaries."""
    state = result.published
    q = tuple(state.mode.tolist())
    return Estimate(
        t_ns=t_ns,
        q_wxyz=q,  # type: ignore[arg-type]
        M=tuple(map(tuple, state.M.tolist())),  # type: ignore[arg-type]
        Z=tuple(state.Z.tolist()),  # type: ignore[arg-type]
        uncertainty_deg=result.uncertainty_deg,
        euler_deg=tuple(math.degrees(a) for a in euler_from_quaternion(q)),  # type: ignore[arg-type]
        counters=dict(counters),
        sensor_t_ns=sensor_t_ns,
        diagnostics=tuple(d.to_dict() for d in result.diagnostics),
    )
