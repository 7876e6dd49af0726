"""Compile the filter's kernels before a live loop starts.

numba compiles each kernel on its first call (``cache=True``: on disk after
that). In a live run that first call would land in the first ticks: on a
fresh install the flight's first half minute would wait for the compiler
(about 30 s of CPU for the compiled tick, benchmarks/RESULTS.md), and its
samples would arrive late (a paced ``sim`` right after installing ended
2.8 deg off reporting 10, when the kernels took 6 s; the same run from the
cache 1.4 deg reporting 4). So the live commands first fuse a few seconds of
the built-in simulator, GNSS included, through a throwaway loop at full
speed: every kernel a tick calls is compiled, or loaded from the cache
(0.3 s), before the first real sample. Nothing of it reaches the outputs;
the live loop starts from its own initial state. When a compile runs for
longer than :data:`fuser.compiling.NOTICE_AFTER_S` (the cache is cold), the
user is told why the command is waiting.
"""

from __future__ import annotations

import time
from typing import Callable

from drivers.sim import SimConfig, simulate
from fuser.compiling import compile_watch
from fuser.config import FuserConfig
from fuser.inputs import SIM_LINK_LATENCY_NS, sim_ticks
from fuser.loop import FusionLoop

__all__ = ["WARM_UP_FLIGHT_S", "warm_up"]

WARM_UP_FLIGHT_S = 4.0
"""Seconds of simulated flight: long enough for the tilt to converge and GNSS aiding to start."""


def warm_up(config: FuserConfig, notice: Callable[[], None] | None = None) -> float:
    """Fuse ``WARM_UP_FLIGHT_S`` of the simulator with ``config`` and discard it; returns the wall seconds it took.
    ``notice`` is called (from a timer thread) when a kernel has been compiling for
    :data:`fuser.compiling.NOTICE_AFTER_S`."""
    start = time.monotonic()
    with compile_watch(notice):
        loop = FusionLoop(config)
        for t_ns, _, samples in sim_ticks(simulate(SimConfig(seed=0, duration_s=WARM_UP_FLIGHT_S, imu_rate_hz=200.0))):
            received = t_ns + SIM_LINK_LATENCY_NS
            loop.advance(received)
            for sample in samples:
                loop.push(sample, received)
        loop.flush()
    return time.monotonic() - start
