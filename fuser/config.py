"""All tuning and wiring of the fuser in one typed object, read from TOML and overridden by flags."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.link import LinkSettings
from fuser.mavlink_out import MavlinkOutSettings
from fuser.ros2 import Ros2Settings

__all__ = ["FuserConfig", "load_config"]


@dataclass(frozen=True)
class FuserConfig:
    """Every setting of the fuser; defaults suit a small multirotor with a MEMS IMU.

    Noise figures are one-sigma. Frames: body FRD, world NED.
    """

    vehicle: str = "sim"
    """Name used in the zenoh key expressions ``bingham_fuser/<vehicle>/...``."""
    rate_hz: float = 100.0
    """Estimates per second (one per tick)."""
    latency_ms: float = 5.0
    """How long a tick waits after its due time for samples still in flight."""
    gyro_noise_rad_s_rt_hz: float = 3e-4
    """Gyro white-noise density."""
    gyro_bias_rad_s: float = 0.015
    """Uncertainty of the gyro bias before it has been learnt (one sigma, per axis)."""
    gyro_bias_floor_rad_s: float = 0.003
    """Uncertainty the bias estimate settles to while it is learnt in motion (integral feedback)."""
    gyro_bias_walk_rad_s_rt_s: float = 1e-4
    """Random walk of the gyro bias (temperature, instability): the bias uncertainty grows by this
    much per square-root second, so a bias learnt at rest is not trusted for ever."""
    bias_time_constant_s: float = 5.0
    """Time constant of the gyro bias estimate (0 disables bias estimation); also the
    correlation time of the residual bias in the process noise."""
    bias_learn_max_rate_rad_s: float = 0.2
    """The bias is learnt only in ticks rotating slower than this, with a trusted accelerometer."""
    rest_min_s: float = 1.5
    """Rest detection (VQF): the sensor counts as at rest once the gyro and accelerometer have stayed
    within ``rest_gyro_rad_s`` and ``rest_accel_m_s2`` of their low-passed values this long; at rest
    the gyro bias is estimated directly from the low-passed gyro (0 disables rest detection)."""
    rest_filter_s: float = 0.5
    """Time constant of the low-pass filters of the rest detector (VQF's restFilterTau)."""
    rest_gyro_rad_s: float = 0.035
    """Rest threshold on the gyro's deviation from its low-pass, and on the low-passed rate itself,
    so that a slow steady turn is not taken for a bias (VQF's restThGyr and biasClip, 2 deg/s)."""
    rest_accel_m_s2: float = 0.5
    """Rest threshold on the accelerometer's deviation from its low-pass (VQF's restThAcc)."""
    rest_bias_sigma_rad_s: float = 5e-4
    """Noise of the low-passed gyro as a measurement of the bias at rest (VQF's biasSigmaRest, 0.03 deg/s)."""
    gyro_scale_error: float = 0.01
    """Relative gyro scale and misalignment error: process noise proportional to the rotation rate."""
    gyro_gap_rate_rad_s: float = 1.0
    """Assumed rotation rate while no gyro data arrives: how fast uncertainty grows in a gap."""
    max_gyro_dt_s: float = 0.1
    """Longer gaps between two gyro samples of one IMU are not integrated."""
    accel_sigma_rad: float = 0.1
    """Direction noise of a raw gravity measurement (used until the tilt is known)."""
    accel_lowpass_s: float = 3.0
    """Longest time constant of the accelerometer low-pass in the gyro-predicted world frame, which is
    also the time constant of tilt corrections once converged (VQF's tauAcc), used once the gyro bias
    is known well (see ``tilt_bias_error_deg``)."""
    tilt_bias_error_deg: float = 0.5
    """Tilt error a residual gyro bias may build up within one tilt-correction time constant: the time
    constant is ``tilt_bias_error / bias sigma``, capped at ``accel_lowpass_s``, so the tilt is corrected
    fast while the bias is unknown and slowly (less linear acceleration in the tilt) once it is learnt."""
    converged_deg: float = 10.0
    """Above this RMS uncertainty the state counts as unconverged: raw accelerometer, fast fixes."""
    accel_gate: float = 0.2
    """Reject the accelerometer when | |f| - g | / g exceeds this (manoeuvres, impacts)."""
    innovation_gate_sigma: float = 3.0
    """Reject a gravity or heading reading further than this many sigma (sensor and state) from the prediction."""
    innovation_reanchor_s: float = 0.5
    """After this long of continuous rejections the reading is accepted again, so a wrong state can recover."""
    tilt_model_error_deg: float = 0.2
    """Published uncertainty only: one-sigma floor of the tilt error the filter cannot see (accelerometer
    bias and misalignment), composed into every estimate as an independent world-frame error (a consider
    term, :mod:`fuser.model_error`; the filter's own state and gains are unchanged). The three model-error
    parameters are fitted on the eight BROAD trials by ``benchmarks/fit_model_error.py``: the highest mean
    log-likelihood of the truth among the sets whose 50/90/95 % regions cover within 5 points of nominal."""
    heading_model_error_deg: float = 3.25
    """Published uncertainty only: one-sigma floor of the heading error the filter cannot see (local
    distortion of the reference field, a magnetometer offset the motion never reveals), composed like
    ``tilt_model_error_deg``; not applied without a magnetometer. Set mostly by BROAD trial 27, whose
    heading sits a steady 4.5-7 deg off (a phone's field); fitted without it, 0.75 deg."""
    rate_model_error_s: float = 0.00225
    """Published uncertainty only: one-sigma attitude error (rad, on every axis) per rad/s of the recent
    RMS rotation rate (low-passed over ``accel_lowpass_s``): time-stamp and synchronisation errors
    (``rate * dt``) and gyro scale or misalignment errors left over the correction time (``s * rate * T``),
    so a time ``dt + s T`` (2.25 ms: 1.1 deg per axis at 500 deg/s)."""
    use_mag: bool = True
    mag_sigma_rad: float = 0.3
    """Heading noise per tick until the state has converged (a fast start), and the least sigma the
    heading innovation gate assumes; once converged see ``mag_error_deg``."""
    mag_error_deg: float = 2.0
    """Heading error of the magnetometer once converged (one sigma): local distortion of the field along
    the path and the tilt error seen through the dip. These errors are correlated over
    ``mag_correlation_s``, so the per-tick sigma is ``mag_error sqrt(mag_correlation_s / dt)``: counted once
    per correlation time, not once per tick. Measured on BROAD 16 (fast translation): the magnetometer's
    heading (through the estimated tilt) sits 1-3 deg off the truth for 10-30 s at a time."""
    mag_correlation_s: float = 10.0
    """Correlation time of the magnetometer's heading error (see ``mag_error_deg``)."""
    heading_bias_error_deg: float = 1.5
    """Heading error a residual gyro bias may build up within one heading-correction time constant: while
    the bias is poorly known the per-tick sigma is lowered to ``sqrt(q) tau / dt`` (``q`` the tick's process
    variance) with ``tau = heading_bias_error / bias sigma``, as for the tilt (``tilt_bias_error_deg``), so
    an unlearnt bias cannot drag the heading away while the magnetometer is trusted slowly."""
    mag_field_ned_gauss: tuple[float, float, float] = (0.21, 0.0, 0.43)
    """Expected earth field (north, east, down): reference for heading, norm and dip gates."""
    mag_norm_gate: float = 0.1
    """Reject the magnetometer when its norm departs from the expected one by this fraction."""
    mag_dip_gate_deg: float = 10.0
    """Reject the magnetometer when its dip departs from the expected one by this much."""
    attitude_sigma_deg: float | None = None
    """If set, autopilot ATTITUDE(_QUATERNION) messages are identity measurements with this noise."""
    zenoh_listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    zenoh_connect: tuple[str, ...] = ()
    record: str | None = None
    """MCAP file to record inputs and estimates to (None: do not record)."""
    link: LinkSettings = LinkSettings()
    """MAVLink vehicle selection, signing and dialect (``[fuser.link]``; see drivers/link.py)."""
    ros2: Ros2Settings = Ros2Settings()
    """ROS 2 output over rmw_zenoh (``[fuser.ros2]``; ``--ros2``): :mod:`fuser.ros2`."""
    mavlink_out: MavlinkOutSettings = MavlinkOutSettings()
    """MAVLink output to ground stations (``[fuser.mavlink_out]``; ``--mavlink-out CONN``): :mod:`fuser.mavlink_out`."""

    def replace(self, **changes: Any) -> FuserConfig:
        """A copy with some settings changed (None values are ignored)."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})


def load_config(path: str | Path | None, **overrides: Any) -> FuserConfig:
    """Defaults, then the TOML file's ``[fuser]`` table (or top level), then ``overrides``.

    Unknown keys are an error naming the key, so a typo never goes unnoticed.
    """
    values: dict[str, Any] = {}
    if path is not None:
        with open(path, "rb") as f:
            data = tomllib.load(f)
        values = data.get("fuser", data)
    known = {f.name: f for f in dataclasses.fields(FuserConfig)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(f"unknown setting(s) in {path}: {', '.join(unknown)}")
    for key, value in list(values.items()):
        if isinstance(value, list):
            values[key] = tuple(value)
        elif isinstance(value, dict) and dataclasses.is_dataclass(known[key].default):
            values[key] = _group(type(known[key].default), key, value, path)
    return FuserConfig(**values).replace(**overrides)


def _group(cls: type, name: str, values: dict[str, Any], path: str | Path | None) -> Any:
    """A settings group from its TOML table ``[fuser.<name>]``; unknown keys are an error naming them."""
    unknown = sorted(set(values) - {f.name for f in dataclasses.fields(cls)})
    if unknown:
        raise ValueError(f"unknown setting(s) in [fuser.{name}] of {path}: {', '.join(f'{name}.{k}' for k in unknown)}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
