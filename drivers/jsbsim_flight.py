"""A fixed-wing flight flown by JSBSim, sensed by the project's sensor model (:func:`drivers.sim.measure`).

JSBSim (jsbsim.org, the ``jsbsim`` package) is a six-degree-of-freedom
flight-dynamics engine: aerodynamics, propulsion, mass properties and the
equations of motion over a rotating WGS84 earth. It flies its Cessna 172
model (``c172x``) through :data:`PROGRAMME`: level flight, a sustained
coordinated 30-degree turn, a climb, a sustained 45-degree turn, a descent
and a 35-degree loiter (four minutes; ``SimConfig.duration_s`` cuts it short).
JSBSim's own c172x autopilot holds the altitude (``ap/altitude_hold``,
``ap/altitude_setpoint``); its heading hold limits the bank to 30 degrees, so
the bank is flown here by a small controller on the ailerons (PI on the bank
error, damped by the roll rate, the commanded bank slewed at 10 deg/s), the
turn is kept coordinated by the rudder against the sideslip, and the throttle
holds 100 knots (the c172x autopilot declares an airspeed hold but does not
implement one).

The truth read from JSBSim after each step, at the IMU rate (``1/imu_rate_hz``
is JSBSim's time step), in the project's frames (body FRD, world NED):

* attitude ``attitude/phi-rad, theta-rad, psi-rad``: Euler 3-2-1 angles of the
  body relative to the local NED frame;
* body rate ``velocities/pi-rad_sec, qi-rad_sec, ri-rad_sec``: relative to
  inertial space, which is what a gyro measures (it includes the earth's
  rotation, 7.3e-5 rad/s, which the fuser does not model: a real gyro has it);
* specific force at the centre of gravity ``accelerations/Nx, Ny, Nz``: the
  non-gravitational acceleration in g (standard gravity 9.80665 m/s^2), body
  axes, with ``Nz`` positive *up* (the normal load factor): specific force FRD
  = ``(Nx, Ny, -Nz) * 9.80665`` and level flight reads (0, 0, -9.8).
  ``accelerations/a-pilot-*`` is the same at the pilot's eye point, which adds
  the lever-arm accelerations of the rotation (up to 1.5 m/s^2 in a roll
  entry); the IMU is taken to sit at the centre of gravity;
* velocity ``velocities/v-north-fps, v-east-fps, v-down-fps`` (ft/s, NED) and
  position ``position/lat-geod-deg, long-gc-deg, h-sl-meters`` (geodetic).

A JSBSim step computes its accelerations from the state it starts from, so
the load factors read after step k + 1 are those of the state read after
step k (one step off, the consistency test sees the difference: 0.07 m/s^2
against 0.01 m/s^2 in a roll entry).

The magnetometer reads the World Magnetic Model's field along the flight
(``SimConfig.mag_field_ned_gauss=None`` in :data:`FIXED_WING`).
``tests/test_jsbsim_flight.py`` checks the truth for consistency: the gyro
integrates to the attitude, and the specific force is the NED acceleration
minus gravity, in the body frame.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .sim import Flight, SimConfig, Trajectory, euler_to_quaternion, measure

__all__ = ["FIXED_WING", "PROGRAMME", "Leg", "fixed_wing_config", "fixed_wing_trajectory", "require_jsbsim", "simulate_fixed_wing"]

FT_M = 0.3048
STANDARD_GRAVITY_M_S2 = 9.80665
MISSING_JSBSIM = "the fixed-wing simulator needs the 'jsbsim' package: pip install 'bingham-fuser[sim]' (or pip install jsbsim)"


@dataclass(frozen=True)
class Leg:
    """From ``start_s`` on: bank ``bank_deg`` (positive right) at ``height_m`` above the start altitude."""

    start_s: float
    bank_deg: float
    height_m: float


PROGRAMME: tuple[Leg, ...] = (
    Leg(0.0, 0.0, 0.0),  # straight and level
    Leg(15.0, 30.0, 0.0),  # sustained coordinated turn, right, 30 deg
    Leg(55.0, 0.0, 150.0),  # wings level, climb 150 m
    Leg(95.0, -45.0, 150.0),  # sustained coordinated turn, left, 45 deg
    Leg(135.0, 0.0, 100.0),  # wings level, descend 50 m
    Leg(150.0, 35.0, 100.0),  # loiter: orbit right at 35 deg to the end
)
PROGRAMME_S = 240.0

FIXED_WING = SimConfig(
    duration_s=PROGRAMME_S,
    vibration_m_s2=1.0,
    vibration_hz=80.0,  # a two-blade propeller at 2400 rpm
    mag_field_ned_gauss=None,  # the WMM's field along the flight
    origin_alt_m=800.0,
)
"""The fixed-wing flight's defaults: the whole programme, engine vibration, the WMM field."""

_AIRSPEED_KTS = 100.0
_ROLL_SLEW_RAD_S = math.radians(10.0)
_BANK_KP, _BANK_KI, _BANK_KD = 1.5, 0.3, 0.3  # aileron per rad of bank error, per rad s, per rad/s of roll rate
_RUDDER_PER_BETA = 3.0  # rudder per rad of sideslip
_THROTTLE_KP, _THROTTLE_KI = 2.0, 0.5  # throttle per unit of relative airspeed error, and per unit s

_TRUTH = (
    "attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad",
    "velocities/pi-rad_sec", "velocities/qi-rad_sec", "velocities/ri-rad_sec",
    "accelerations/Nx", "accelerations/Ny", "accelerations/Nz",
    "velocities/v-north-fps", "velocities/v-east-fps", "velocities/v-down-fps",
    "position/lat-geod-deg", "position/long-gc-deg", "position/h-sl-meters",
)


def require_jsbsim():
    """The ``jsbsim`` module, or ImportError saying how to install it."""
    try:
        import jsbsim
    except ImportError as exc:
        raise ImportError(MISSING_JSBSIM) from exc
    return jsbsim


def _aircraft(config: SimConfig, heading_deg: float):
    """A JSBSim c172x in the air at the origin, at 100 knots, engine running, trimmed for level flight."""
    jsbsim = require_jsbsim()
    jsbsim.FGJSBBase().debug_lvl = 0  # no start-up banner on stdout
    fdm = jsbsim.FGFDMExec(jsbsim.get_default_root_dir())
    fdm.set_debug_level(0)
    fdm.load_model("c172x")
    fdm.set_dt(1.0 / config.imu_rate_hz)
    fdm["simulation/randomseed"] = config.seed
    fdm["ic/lat-geod-deg"] = config.origin_lat_deg
    fdm["ic/long-gc-deg"] = config.origin_lon_deg
    fdm["ic/h-sl-ft"] = config.origin_alt_m / FT_M
    fdm["ic/vc-kts"] = _AIRSPEED_KTS
    fdm["ic/psi-true-deg"] = heading_deg
    fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    fdm["fcs/mixture-cmd-norm"] = 1.0
    fdm["fcs/throttle-cmd-norm"] = 0.6
    fdm["simulation/do_simple_trim"] = 0  # longitudinal trim: throttle and elevator for level flight
    fdm["ap/altitude_setpoint"] = config.origin_alt_m / FT_M
    fdm["ap/altitude_hold"] = 1
    return fdm


def fixed_wing_trajectory(config: SimConfig = FIXED_WING, programme: tuple[Leg, ...] = PROGRAMME, heading_deg: float = 30.0) -> Trajectory:
    """Fly ``programme`` in JSBSim for ``config.duration_s`` at ``config.imu_rate_hz``; the true motion."""
    fdm = _aircraft(config, heading_deg)
    n = int(round(config.duration_s * config.imu_rate_hz))
    dt = 1.0 / config.imu_rate_hz
    starts = np.array([leg.start_s for leg in programme])
    truth = np.empty((n + 1, len(_TRUTH)))
    bank_cmd = bank_integral = 0.0
    throttle_integral = fdm["fcs/throttle-cmd-norm"]  # the trimmed setting
    for k in range(n + 1):
        leg = programme[int(np.searchsorted(starts, k * dt, side="right")) - 1]
        target = math.radians(leg.bank_deg)
        bank_cmd += max(-_ROLL_SLEW_RAD_S * dt, min(_ROLL_SLEW_RAD_S * dt, target - bank_cmd))
        error = bank_cmd - fdm["attitude/phi-rad"]
        bank_integral += error * dt
        fdm["fcs/aileron-cmd-norm"] = _clip(_BANK_KP * error + _BANK_KI * bank_integral - _BANK_KD * fdm["velocities/p-rad_sec"], -1.0, 1.0)
        fdm["fcs/rudder-cmd-norm"] = _clip(-_RUDDER_PER_BETA * fdm["aero/beta-rad"], -1.0, 1.0)
        speed_error = (_AIRSPEED_KTS - fdm["velocities/vc-kts"]) / _AIRSPEED_KTS
        throttle_integral = _clip(throttle_integral + _THROTTLE_KI * speed_error * dt, 0.0, 1.0)
        fdm["fcs/throttle-cmd-norm"] = _clip(throttle_integral + _THROTTLE_KP * speed_error, 0.0, 1.0)
        fdm["ap/altitude_setpoint"] = (config.origin_alt_m + leg.height_m) / FT_M
        fdm.run()
        truth[k] = [fdm[name] for name in _TRUTH]
    # A step computes its accelerations from the state it starts from: the load factors read after
    # step k + 1 belong to the state read after step k.
    euler, rates, load = truth[:n, 0:3], truth[:n, 3:6], truth[1:, 6:9]
    truth = truth[:n]
    specific_force = STANDARD_GRAVITY_M_S2 * np.column_stack([load[:, 0], load[:, 1], -load[:, 2]])
    return Trajectory(
        t_s=np.arange(n) * dt,
        q_true=euler_to_quaternion(euler),
        gyro_true_rad_s=rates,
        accel_true_m_s2=specific_force,
        vel_ned_true_m_s=truth[:, 9:12] * FT_M,
        lat_true_deg=truth[:, 12],
        lon_true_deg=truth[:, 13],
        alt_true_m=truth[:, 14],
    )


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def simulate_fixed_wing(config: SimConfig = FIXED_WING, programme: tuple[Leg, ...] = PROGRAMME) -> Flight:
    """The fixed-wing flight under ``config``'s sensor model; deterministic for a given seed."""
    return measure(config, fixed_wing_trajectory(config, programme))


def fixed_wing_config(**changes) -> SimConfig:
    """:data:`FIXED_WING` with some fields changed, e.g. ``fixed_wing_config(duration_s=30, gnss=False)``."""
    return dataclasses.replace(FIXED_WING, **changes)
