"""Compile the filter's kernels before a live clock starts.

numba compiles each kernel on its first call (``cache=True``: on disk after
that, :mod:`core.bingham_kernels`, :mod:`core.saddlepoint`). In a live run
that first call lands in the first ticks: on a fresh install the flight's
first seconds would wait for the compiler (some 6 s; 15 s before the kernels
were arranged to compile once each, benchmarks/RESULTS.md), and their samples
arrive late (a paced ``sim`` right after installing ended 2.8 deg off
reporting 10, the same run from the cache 1.4 deg reporting 4). So the live
commands first fuse a few seconds of the built-in simulator, GNSS included,
through a throwaway loop at full speed: every kernel a tick calls is
compiled, or loaded from the cache, before the first real sample. Nothing of it reaches
the outputs; the live loop starts from its own initial state.
"""

from __future__ import annotations

import time

from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from fuser.inputs import SIM_LINK_LATENCY_NS, sim_ticks
from fuser.loop import FusionLoop

__all__ = ["WARM_UP_FLIGHT_S", "warm_up"]

WARM_UP_FLIGHT_S = 4.0
"""Seconds of simulated flight: long enough for the tilt to converge and GNSS aiding to start."""


def warm_up(config: FuserConfig) -> float:
    """Fuse ``WARM_UP_FLIGHT_S`` of the simulator with ``config`` and discard it; returns the wall seconds it took."""
    start = time.monotonic()
    loop = FusionLoop(config)
    for t_ns, _, samples in sim_ticks(simulate(SimConfig(seed=0, duration_s=WARM_UP_FLIGHT_S, imu_rate_hz=200.0))):
        received = t_ns + SIM_LINK_LATENCY_NS
        loop.advance(received)
        for sample in samples:
            loop.push(sample, received)
    loop.flush()
    return time.monotonic() - start
