"""The heading held on the gyro: the published heading widens with the bias error along the vertical, held.

While no magnetometer reading or autopilot attitude corrects the heading (a disturbed field kept out by its norm or
dip gate), the bias error along the vertical turns the heading by itself times the time held; the prediction counts
the residual bias as correlated over ``fuser.bias.time_constant_s`` only (the in-motion learning corrects the
horizontal axes within it). ``fuser.model.bias.held_heading_variance_rad2`` adds the difference, checked here
against the closed form; ``benchmarks/heading_drift.py`` and ``benchmarks/broad.py --loto`` show it on BROAD's trial
32 (a magnet attached to the sensor): its 90 % region held the truth 73 % of the time out of sample, 87 % with it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fuser.config import FuserConfig
from fuser.model import bias
from fuser.model.fusion import _heading_held_s
from fuser.model.state import initial_state
from model_records import params, set_fields

COVARIANCE = np.diag([1e-6, 4e-6, 9e-6])  # (rad/s)^2: sigma 1, 2, 3 mrad/s on body x, y, z


def _variance(q_wxyz, held_s, feedback=True):
    config = FuserConfig().replace(bias={"feedback_enabled": feedback})
    state = initial_state(config)
    state.bias.covariance_rad2_s2[:] = COVARIANCE
    return bias.held_heading_variance_rad2(params(config).bias, state.bias, tuple(q_wxyz), held_s), config.bias


@pytest.mark.parametrize("rotvec", [(0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (math.pi / 2, 0.0, 0.0), (0.4, -0.7, 2.0)])
@pytest.mark.parametrize("held_s", [2.0, 30.0, 90.0])
def test_the_held_heading_variance_is_the_vertical_bias_held_less_what_the_prediction_counted(rotvec, held_s):
    r = Rotation.from_rotvec(rotvec)  # body -> NED
    x, y, z, w = r.as_quat()
    got, settings = _variance((w, x, y, z), held_s)
    down_body = r.inv().apply([0.0, 0.0, 1.0])
    vertical = down_body @ COVARIANCE @ down_body
    counted = np.trace(COVARIANCE) / 3.0 * settings.time_constant_s * held_s
    assert got == pytest.approx(max(0.0, vertical * held_s**2 - counted), rel=1e-12, abs=1e-18)


def test_level_and_long_held_it_is_the_z_bias_times_the_time():
    got, settings = _variance((1.0, 0.0, 0.0, 0.0), 60.0)
    assert got == pytest.approx(9e-6 * 3600.0 - 14e-6 / 3.0 * settings.time_constant_s * 60.0)
    assert math.degrees(math.sqrt(got)) == pytest.approx(10.1, abs=0.1)  # 3 mrad/s for a minute: about 10 deg
    short, _ = _variance((1.0, 0.0, 0.0, 0.0), 1.0)
    assert short == 0.0  # within the correlation time the prediction already counts it


def test_without_the_feedback_the_longer_correlation_is_taken_off():
    with_feedback, _ = _variance((1.0, 0.0, 0.0, 0.0), 30.0, feedback=True)
    without, settings = _variance((1.0, 0.0, 0.0, 0.0), 30.0, feedback=False)
    assert with_feedback - without == pytest.approx(14e-6 / 3.0 * (settings.correlation_without_feedback_s - settings.time_constant_s) * 30.0)


def test_the_heading_is_held_since_the_latest_correction_of_either_source():
    state = initial_state(FuserConfig())
    assert _heading_held_s(state.heading, state.attitude_source, 5_000_000_000) == 0.0  # never corrected: nothing held
    set_fields(state.heading, last_fused_ns=2_000_000_000)
    assert _heading_held_s(state.heading, state.attitude_source, 5_000_000_000) == pytest.approx(3.0)
    set_fields(state.attitude_source, last_fused_ns=4_500_000_000)
    assert _heading_held_s(state.heading, state.attitude_source, 5_000_000_000) == pytest.approx(0.5)
    set_fields(state.heading, last_fused_ns=4_900_000_000)
    assert _heading_held_s(state.heading, state.attitude_source, 5_000_000_000) == pytest.approx(0.1)
