"""The simulated vehicle into the loop: the default job when no drone is at hand.

The simulator's MAVLink bytes (or DroneCAN frames) go through the real
decoders, then the same pipeline as live data. Paced to the wall clock
(``speed=1``), faster (``speed=10``): then each sample is received at the
:class:`~fuser.wallclock.WallClock`'s time, Unix nanoseconds, like live data.
Or as fast as possible (``speed=0``): then the receive time is the send time
plus a fixed link latency, on the simulated flight's own clock, and the run
is deterministic (all but the status's zenoh entry, whose ``subscribed`` says
whether anyone listened). Truth goes to its sinks as ``(t_ns, q, log_ns)``: ``t_ns``
on the vehicle's own clock, the clock of each estimate's ``sensor_t_ns`` (so
scoring needs no alignment), and ``log_ns`` the receive time of that IMU tick,
so that truth and estimates are recorded on one timeline.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from itertools import chain
from typing import Callable, Sequence

from drivers.sim import Flight
from fuser.inputs import SIM_LINK_LATENCY_NS, sim_ticks
from fuser.pipeline import STATUS_PERIOD_NS, Pipeline
from fuser.wallclock import WallClock

__all__ = ["SimRun", "run_sim"]


@dataclass(frozen=True)
class SimRun:
    samples: int
    estimates: int
    wall_s: float


def run_sim(
    pipeline: Pipeline,
    flight: Flight,
    transport: str = "mavlink",
    speed: float = 1.0,
    truth_sinks: Sequence[Callable[[int, tuple, int], None]] = (),
    should_stop: Callable[[], bool] = lambda: False,
    truth_rate_hz: float = 100.0,
    clock: WallClock | None = None,
    status_sinks: Sequence[Callable[[int, dict], None]] = (),
    health: Callable[[], dict] = dict,
) -> SimRun:
    """Fly a simulated flight through ``pipeline``; returns counts and wall time.

    Truth goes to ``truth_sinks`` at most ``truth_rate_hz`` times a second
    (slerp between 100 Hz samples is far more accurate than any estimate).
    A paced run receives on ``clock`` (default: measured now, running ``speed``
    times as fast as real time, so the loop ticks at its rate in flight time).
    Once a second of flight the status (:meth:`Pipeline.status` and the
    outputs' ``health``, as a live run's) goes to ``status_sinks`` as
    ``(receive_ns, status)``.
    """
    clock = (clock or WallClock.start(speed)) if speed > 0 else None
    start_mono = time.monotonic_ns()
    ticks = sim_ticks(flight, transport)
    first = next(ticks, None)  # the simulator lays out the whole flight's samples here (50-150 ms): not flight time
    start_wall = clock.now_ns() if clock is not None else 0
    t0 = int(flight.t_ns[0])
    truth_period = round(1e9 / truth_rate_hz)
    next_truth = t0
    next_status = t0 + STATUS_PERIOD_NS
    samples = 0
    for t_ns, q_true, tick in chain([] if first is None else [first], ticks):
        if should_stop():
            break
        if clock is not None:
            due = start_wall + (t_ns - t0)
            while (now := clock.now_ns()) < due:
                pipeline.advance(now)
                clock.sleep_until(due, 0.002)
            received = clock.now_ns()
        else:
            received = t_ns + SIM_LINK_LATENCY_NS
        pipeline.advance(received)  # as feed does: the ticks due by now are recorded before the truth received with this tick
        if t_ns >= next_truth:
            next_truth += truth_period
            for sink in truth_sinks:
                sink(t_ns, tuple(float(v) for v in q_true), received)
        for sample in tick:
            pipeline.feed(sample, received)
            samples += 1
        if status_sinks and t_ns >= next_status:
            next_status += STATUS_PERIOD_NS
            status = {**pipeline.status(), **health()}
            for status_sink in status_sinks:
                status_sink(received, status)
    pipeline.finish()
    return SimRun(samples, pipeline.estimates, (time.monotonic_ns() - start_mono) / 1e9)
