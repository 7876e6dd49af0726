"""The fast start in a turn, against the closed form of a level coordinated turn.

Banked ``phi`` about the body's x axis, heading north, turning right: the centripetal acceleration is
``a = (0, g tan phi, 0)`` (NED), the specific force ``f = a - g e_z``, and in the body ``-f`` lies along the body's
z axis (the lift), ``g / cos phi`` long, ``phi`` from down. A raw reading is then the bank's false vertical; with the
GNSS acceleration taken out it measures ``g e_z - a`` (fuser/model/gravity.py). The dip gate compares the field's
angle to the measured specific force with the reference field's angle to what that was measured as: both free of
the estimate (fuser/model/heading.py). Every expected value here is computed from these vectors by hand.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import quaternion as quat
from drivers.samples import GnssSample, SourceId
from fuser.config import AccelSettings, FuserConfig, MagSettings
from fuser.model.diagnostics import DIAGNOSTIC
from fuser.model.gravity import DOWN_NED, update_gravity
from fuser.model.heading import update_heading
from fuser.model.state import FilterState, initial_state
from fuser.model.tick import TickContext
from fuser.model.velocity import raw_world, track_velocity
from model_records import gnss_input, params, part, update_diagnostic

G = AccelSettings().gravity_m_s2
P = params()
PHI = math.radians(30.0)
TRUTH = quat.from_axis_angle([1.0, 0.0, 0.0], PHI)  # body FRD -> NED, banked 30 deg right, heading north
LEVEL = tuple(quat.IDENTITY)
LIFT_BODY = np.array([0.0, 0.0, -G / math.cos(PHI)])  # the accelerometer's reading (specific force) in the body
LIFT = tuple(LIFT_BODY)
GNSS_WORLD = np.array([0.0, -G * math.tan(PHI), G])  # g e_z - a
GNSS = (True, tuple(GNSS_WORLD), 0.3)  # what a raw reading measures (present, g e_z - a, its noise in m/s^2: 1.7 deg of its direction)
NO_GNSS = (False, (0.0, 0.0, 0.0), 0.0)
FIELD_NED = (0.2, 0.0, 0.4)
TICK = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=3.0, prior_tilt_doubt_deg=2.0)


def test_the_closed_form_turn():
    assert np.allclose(quat.to_matrix(TRUTH) @ -LIFT_BODY, GNSS_WORLD)


def _converged_level() -> np.record:
    """Converged on raw readings in the turn: the estimate level (the bank's false vertical), the low-pass the lift."""
    return part("gravity", accel_lp_m_s2=LIFT_BODY.copy(), converged=True, tilt_known=True)


def test_a_state_converged_on_the_banks_vertical_starts_again_when_gnss_shows_it():
    """Level estimate, true bank 30 deg: the raw reading seen through the estimate is 30 deg from ``g e_z - a``,
    beyond the raw gate ``3 hypot(accel.sigma_rad, GNSS noise, tilt doubt)`` = 3 hypot(5.73, 1.52, 2) = 18.8 deg
    (the noise 0.3 m/s^2 over ``|g e_z - a|`` = 11.3 m/s^2): the fast start runs again (unconverged, the reading
    measuring ``g e_z - a`` with that sigma, applied at once)."""
    state = _converged_level()
    reading = update_gravity(P.accel, P.updates, state, TICK, LIFT, 3.0, LEVEL, 0.01, True, *GNSS)
    assert reading.restart and reading.apply_now
    assert not state.converged and state.gnss_checked and not state.has_accel_lp
    diagnostic = update_diagnostic(reading.diagnostic)
    assert diagnostic.innovation_deg == pytest.approx(30.0, abs=1e-9)
    assert diagnostic.sigma_deg == pytest.approx(math.degrees(math.hypot(0.1, 0.3 / (G / math.cos(PHI)))), rel=1e-9)
    np.testing.assert_allclose(state.measured_world, GNSS_WORLD / np.linalg.norm(GNSS_WORLD), atol=1e-12)
    # the likelihood it fuses peaks at the truth: the exponent's quadratic form is largest there among these
    exponent = reading.exponent
    level, truth = quat.IDENTITY, TRUTH
    assert truth @ exponent @ truth > level @ exponent @ level + 1.0


def test_a_state_that_agrees_with_gnss_is_kept_and_checked_once():
    state = part("gravity", accel_lp_m_s2=LIFT_BODY.copy(), converged=True, tilt_known=True)
    agreeing = update_gravity(P.accel, P.updates, state, TICK, LIFT, 3.0, tuple(TRUTH), 0.01, True, *GNSS)
    assert not agreeing.restart and state.converged and state.gnss_checked
    # once checked, a later disagreement is the gravity update's own business (its gate), not a new start
    later = update_gravity(P.accel, P.updates, state, TICK, LIFT, 3.0, LEVEL, 0.01, True, *GNSS)
    assert not later.restart
    # no GNSS: nothing to check against
    alone_state = _converged_level()
    alone = update_gravity(P.accel, P.updates, alone_state, TICK, LIFT, 3.0, LEVEL, 0.01, True, *NO_GNSS)
    assert not alone.restart and not alone_state.gnss_checked


def test_until_converged_every_gnss_reading_checks_the_state():
    """Checked once and not yet converged (the first pair's acceleration, the noisiest, agreed within the gate): the
    next GNSS reading still checks the state and starts again on the bank's vertical. A raw reading whose norm
    underflows (1e-171 m/s^2: no direction) shows no disagreement, and does not divide by its norm (a
    ZeroDivisionError the any-input property test found when the check first ran on every reading)."""
    state = part("gravity", tilt_known=True, converged=False, gnss_checked=True)
    assert update_gravity(P.accel, P.updates, state, TICK, LIFT, 3.0, LEVEL, 0.01, True, *GNSS).restart
    state = part("gravity", tilt_known=True, converged=False, gnss_checked=True)
    assert not update_gravity(P.accel, P.updates, state, TICK, (1e-171, 0.0, 0.0), 3.0, LEVEL, 0.01, True, *GNSS).restart


def test_the_dip_gate_does_not_depend_on_the_estimate():
    """The truth's field in the body, with the specific force measured along the body's z and known (GNSS) to be
    ``g e_z - a``: the dip gate passes whatever the estimate (a heading 120 deg off and a tilt 40 deg off included).
    Taken for down instead (no GNSS), the same reading is 12.7 deg off the reference dip: gated."""
    mag_body = quat.to_matrix(TRUTH).T @ np.array(FIELD_NED)
    reference = np.array(FIELD_NED)
    wrong = quat.multiply(quat.from_axis_angle([0.0, 0.0, 1.0], math.radians(120.0)), quat.from_axis_angle([0.0, 1.0, 0.0], math.radians(40.0)))
    aided = part("gravity", tilt_known=True, converged=True, measured_body=np.array([0.0, 0.0, 1.0]),
                 measured_world=GNSS_WORLD / np.linalg.norm(GNSS_WORLD))
    h = update_heading(P.mag, P.updates, reference, part("heading"), aided, TICK, tuple(mag_body), tuple(wrong), 0.05, 6.0)
    assert update_diagnostic(h.diagnostic).reason != "dip", update_diagnostic(h.diagnostic)
    plain = part("gravity", tilt_known=True, converged=True, measured_body=np.array([0.0, 0.0, 1.0]), measured_world=DOWN_NED)
    h = update_heading(P.mag, P.updates, reference, part("heading"), plain, TICK, tuple(mag_body), tuple(TRUTH), 0.05, 6.0)
    assert update_diagnostic(h.diagnostic).reason == "dip"
    field = np.array(FIELD_NED) / np.linalg.norm(FIELD_NED)
    lift = quat.to_matrix(TRUTH) @ np.array([0.0, 0.0, 1.0])
    off = math.degrees(math.acos(field @ lift) - math.acos(field @ DOWN_NED))
    assert off == pytest.approx(12.7, abs=0.05) and off > MagSettings().dip_gate_deg


def _fix(t_ns: int, vel, accuracy_m_s: float) -> GnssSample:
    return GnssSample(t_ns, 3, tuple(vel), False, accuracy_m_s, None, None, None, False, SourceId("mavlink", 1, 1, 0))


def _paired(velocities, accuracy_m_s: float) -> FilterState:
    """A fresh state (its ``velocity`` part and the accelerometer's history) after a fix every 0.1 s, one stream (slot 0)."""
    state = initial_state(FuserConfig())
    for k, vel in enumerate(velocities):
        placed = 1_000_000_000 + k * 100_000_000
        track_velocity(P.gnss, P.accel, P.updates, state.velocity, state.knots_ns, state.knots,
                       gnss_input([(_fix(placed, vel, accuracy_m_s), placed, 0)]), part("gravity"), False, (0.0, 0.0, 0.0), placed,
                       10_000_000, LEVEL, 90.0, 90.0, 3.0, False, np.zeros(1, DIAGNOSTIC), 0)
    return state


def _gnss_off() -> np.record:
    """The ``gnss`` parameters with GNSS off."""
    return params(FuserConfig().replace(gnss={"enabled": False})).gnss


def test_the_pairs_of_fixes_are_what_raw_readings_measure_until_they_are_old():
    """Two fixes 0.1 s apart (no vertical velocity), 0.05 m/s accurate, differ by (0, 0.5, 0) m/s: ``a`` = (0, 5, 0)
    m/s^2, ``g e_z - a`` = (0, -5, g), its noise ``sqrt(2) 0.05 / 0.1`` = 0.71 m/s^2, measured at the middle of the
    pair (0.15 s latency); aiding or not (no accelerometer history yet). Past ``gnss.max_age_s`` plus the latency it
    is not used; nor an acceleration within three times its noise (0.3 m/s receivers: 4.2 m/s^2)."""
    gnss, accel = P.gnss, P.accel
    state = _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0)], 0.05).velocity
    present, world, noise_m_s2 = raw_world(gnss, accel, state, 1_100_000_000)
    assert present
    np.testing.assert_allclose(world, [0.0, -5.0, G], atol=1e-9)
    assert noise_m_s2 == pytest.approx(math.sqrt(2.0) * 0.05 / 0.1, rel=1e-9)
    assert state.recent_ns == 1_000_000_000 + 50_000_000 - 150_000_000
    assert not raw_world(gnss, accel, state, state.recent_ns + 1_150_000_001)[0]
    assert not raw_world(_gnss_off(), accel, state, 1_100_000_000)[0]
    assert not raw_world(gnss, accel, _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0)], 0.3).velocity, 1_100_000_000)[0]
    # a third fix, a = (0, 2, 0): the low-pass over gnss.raw_lowpass_s (0.3 s) starts as the running mean of its pairs
    three = _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0), (10.0, 0.7, 0.0)], 0.05).velocity
    np.testing.assert_allclose(three.recent_world_m_s2, [0.0, -(5.0 + 2.0) / 2.0, G], atol=1e-9)
    assert three.recent_noise_var_m2_s4 == pytest.approx(2.0 * 0.05 ** 2 / 0.2 ** 2, rel=1e-9)  # (v_2 - v_0) / 0.2 s


def test_without_a_heading_measurement_the_tilt_alone_decides_convergence():
    """6-D (the magnetometer off): the heading is never known, so the whole doubt never falls below
    ``updates.converged_deg`` and raw readings, linear accelerations and all, would be taken for ever; the tilt's
    doubt decides instead. With a heading measured the whole doubt does, as before."""
    six_d, nine_d = part("gravity", tilt_known=True), part("gravity", tilt_known=True)  # the same level state, twice
    unsure_heading = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=90.0, prior_tilt_doubt_deg=2.0)
    at_rest = (0.0, 0.0, -G)
    update_gravity(P.accel, P.updates, six_d, unsure_heading, at_rest, 3.0, LEVEL, 0.01, False, *NO_GNSS)
    assert six_d.converged and six_d.has_accel_lp
    update_gravity(P.accel, P.updates, nine_d, unsure_heading, at_rest, 3.0, LEVEL, 0.01, True, *NO_GNSS)
    assert not nine_d.converged and not nine_d.has_accel_lp


@pytest.mark.parametrize("interval_s, factor", [(0.0025, 2.0), (0.005, math.sqrt(2.0)), (0.01, 1.0), (0.1, 1.0)])
def test_a_fast_start_reading_counts_per_ten_milliseconds(interval_s, factor):
    """A raw reading's sigma is ``accel.sigma_rad`` per ``updates.fast_start_interval_s`` (10 ms) of readings:
    readings every 2.5 / 5 ms are 2 / sqrt(2) times as noisy (the same information per second, ``1 / (sigma^2 T)``),
    sparser ones as given. Level and at rest, at a cold start (the prior's doubt above ``updates.converged_deg``)."""
    cold = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=60.0, prior_tilt_doubt_deg=50.0)
    state = part("gravity")
    reading = update_gravity(P.accel, P.updates, state, cold, (0.0, 0.0, -G), 3.0, LEVEL, interval_s, True, *NO_GNSS)
    assert not state.converged and reading.apply_now
    assert update_diagnostic(reading.diagnostic).sigma_deg == pytest.approx(math.degrees(AccelSettings().sigma_rad * factor), rel=1e-12)
