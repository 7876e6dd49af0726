"""Named simulated flights, with the faults a real flight log has.

The multirotor scenarios are windows of :func:`drivers.sim.simulate`'s
programme, optionally with a magnet near the sensor or a lossy IMU link;
``logs/`` holds them and the tests replay them. The fixed-wing scenarios are
JSBSim's (:mod:`drivers.jsbsim_flight`, needs the ``jsbsim`` package), with
and without GNSS, so that what GNSS aiding buys can be measured.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import jsbsim_flight
from .sim import Flight, SimConfig, simulate

__all__ = ["SCENARIOS", "flight", "require", "scenario"]

SCENARIOS: dict[str, str] = {
    "hover": "the first 12 s: hover with small attitude changes",
    "aggressive": "4-32 s: hover, banked turns, then fast manoeuvres up to 500 deg/s",
    "magnet": "hover with a magnet brought near the sensor from 6 s to 9 s",
    "dropout": "hover and turns with 20% of IMU samples lost and a 0.5 s outage",
    "fixedwing": "JSBSim Cessna 172, 4 min: sustained 30 and 45 deg coordinated turns, a climb, a 35 deg loiter; with GNSS",
    "fixedwing-nognss": "the same fixed-wing flight without GNSS",
}

_MAGNET_GAUSS = np.array([0.35, -0.25, 0.1])
"""Body-frame field of the magnet at its closest (stronger than the earth's)."""


def _window(flight: Flight, start_s: float, end_s: float) -> Flight:
    t = (flight.t_ns - flight.t_ns[0]) * 1e-9
    keep = (t >= start_s) & (t < end_s)
    return flight.cut(int(np.argmax(keep)), int(len(keep) - np.argmax(keep[::-1])))


_FIXED_WING = ("fixedwing", "fixedwing-nognss")


def require(name: str) -> None:
    """Raise ImportError naming the package a scenario needs and how to install it, if it is missing."""
    if name in _FIXED_WING:
        jsbsim_flight.require_jsbsim()


def scenario(name: str, seed: int = 0, imu_rate_hz: float = 200.0) -> Flight:
    """The named scenario's flight (see :data:`SCENARIOS`), deterministic for a seed."""
    if name == "hover":
        return _window(simulate(SimConfig(seed=seed, duration_s=12.0, imu_rate_hz=imu_rate_hz)), 0.0, 12.0)
    if name == "aggressive":
        return _window(simulate(SimConfig(seed=seed, duration_s=32.0, imu_rate_hz=imu_rate_hz)), 4.0, 32.0)
    if name == "magnet":
        flight = simulate(SimConfig(seed=seed, duration_s=12.0, imu_rate_hz=imu_rate_hz))
        t = (flight.t_ns - flight.t_ns[0]) * 1e-9
        closeness = np.clip(np.minimum(t - 6.0, 9.0 - t), 0.0, 0.5) / 0.5  # ramps in and out over 0.5 s
        return dataclasses.replace(flight, mag_gauss=flight.mag_gauss + closeness[:, None] * _MAGNET_GAUSS)
    if name == "dropout":
        flight = simulate(SimConfig(seed=seed, duration_s=16.0, imu_rate_hz=imu_rate_hz, dropout_probability=0.2))
        t = (flight.t_ns - flight.t_ns[0]) * 1e-9
        return dataclasses.replace(flight, imu_valid=flight.imu_valid & ~((t >= 11.0) & (t < 11.5)))
    if name in _FIXED_WING:
        config = jsbsim_flight.fixed_wing_config(seed=seed, imu_rate_hz=imu_rate_hz, gnss=name == "fixedwing")
        return jsbsim_flight.simulate_fixed_wing(config)
    raise ValueError(f"unknown scenario {name!r}; choose from {', '.join(SCENARIOS)}")


def flight(name: str, seed: int = 0, imu_rate_hz: float = 400.0, duration_s: float = 60.0) -> Flight:
    """``"full"``: the whole programme for ``duration_s``; otherwise the named :func:`scenario`."""
    if name == "full":
        return simulate(SimConfig(seed=seed, duration_s=duration_s, imu_rate_hz=imu_rate_hz))
    return scenario(name, seed, imu_rate_hz)
