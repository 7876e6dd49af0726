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
from fuser.config import AccelSettings, GnssSettings, MagSettings, UpdateSettings
from fuser.model.gravity import DOWN_NED, GnssWorld, update_gravity
from fuser.model.heading import FieldReference, update_heading
from fuser.model.state import GravityState, HeadingState, VelocityState
from fuser.model.tick import TickContext
from fuser.model.velocity import raw_world, track_velocity

G = AccelSettings().gravity_m_s2
PHI = math.radians(30.0)
TRUTH = quat.from_axis_angle([1.0, 0.0, 0.0], PHI)  # body FRD -> NED, banked 30 deg right, heading north
LIFT_BODY = np.array([0.0, 0.0, -G / math.cos(PHI)])  # the accelerometer's reading (specific force) in the body
GNSS_WORLD = np.array([0.0, -G * math.tan(PHI), G])  # g e_z - a
GNSS = GnssWorld(GNSS_WORLD, 0.3)  # its noise, m/s^2: 1.7 deg of its direction
FIELD_NED = (0.2, 0.0, 0.4)
TICK = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=3.0, prior_tilt_doubt_deg=2.0)


def test_the_closed_form_turn():
    assert np.allclose(quat.to_matrix(TRUTH) @ -LIFT_BODY, GNSS_WORLD)


def _converged_level() -> GravityState:
    """Converged on raw readings in the turn: the estimate level (the bank's false vertical), the low-pass the lift."""
    return GravityState(accel_lp_m_s2=LIFT_BODY.copy(), converged=True, tilt_known=True)


def test_a_state_converged_on_the_banks_vertical_starts_again_when_gnss_shows_it():
    """Level estimate, true bank 30 deg: the raw reading seen through the estimate is 30 deg from ``g e_z - a``,
    beyond the raw gate ``3 hypot(accel.sigma_rad, GNSS noise, tilt doubt)`` = 3 hypot(5.73, 1.52, 2) = 18.8 deg
    (the noise 0.3 m/s^2 over ``|g e_z - a|`` = 11.3 m/s^2): the fast start runs again (unconverged, the reading
    measuring ``g e_z - a`` with that sigma, applied at once)."""
    reading = update_gravity(AccelSettings(), UpdateSettings(), _converged_level(), TICK, LIFT_BODY, 3.0, quat.IDENTITY.copy(), 0.01,
                             gnss=GNSS)
    assert reading.restart and reading.apply_now
    assert not reading.state.converged and reading.state.gnss_checked and reading.state.accel_lp_m_s2 is None
    assert reading.diagnostic.innovation_deg == pytest.approx(30.0, abs=1e-9)
    assert reading.diagnostic.sigma_deg == pytest.approx(math.degrees(math.hypot(0.1, 0.3 / (G / math.cos(PHI)))), rel=1e-9)
    np.testing.assert_allclose(reading.state.measured_world, GNSS_WORLD / np.linalg.norm(GNSS_WORLD), atol=1e-12)
    # the likelihood it fuses peaks at the truth: the exponent's quadratic form is largest there among these
    exponent = reading.exponent
    level, truth = quat.IDENTITY, TRUTH
    assert truth @ exponent @ truth > level @ exponent @ level + 1.0


def test_a_state_that_agrees_with_gnss_is_kept_and_checked_once():
    state = GravityState(accel_lp_m_s2=LIFT_BODY.copy(), converged=True, tilt_known=True)
    agreeing = update_gravity(AccelSettings(), UpdateSettings(), state, TICK, LIFT_BODY, 3.0, TRUTH, 0.01, gnss=GNSS)
    assert not agreeing.restart and agreeing.state.converged and agreeing.state.gnss_checked
    # once checked, a later disagreement is the gravity update's own business (its gate), not a new start
    later = update_gravity(AccelSettings(), UpdateSettings(), agreeing.state, TICK, LIFT_BODY, 3.0, quat.IDENTITY.copy(), 0.01, gnss=GNSS)
    assert not later.restart
    # no GNSS: nothing to check against
    alone = update_gravity(AccelSettings(), UpdateSettings(), _converged_level(), TICK, LIFT_BODY, 3.0, quat.IDENTITY.copy(), 0.01)
    assert not alone.restart and not alone.state.gnss_checked


def test_the_dip_gate_does_not_depend_on_the_estimate():
    """The truth's field in the body, with the specific force measured along the body's z and known (GNSS) to be
    ``g e_z - a``: the dip gate passes whatever the estimate (a heading 120 deg off and a tilt 40 deg off included).
    Taken for down instead (no GNSS), the same reading is 12.7 deg off the reference dip: gated."""
    mag_body = quat.to_matrix(TRUTH).T @ np.array(FIELD_NED)
    reference = FieldReference.of(FIELD_NED)
    wrong = quat.multiply(quat.from_axis_angle([0.0, 0.0, 1.0], math.radians(120.0)), quat.from_axis_angle([0.0, 1.0, 0.0], math.radians(40.0)))
    aided = GravityState(tilt_known=True, converged=True, measured_body=np.array([0.0, 0.0, 1.0]),
                         measured_world=GNSS_WORLD / np.linalg.norm(GNSS_WORLD))
    h = update_heading(MagSettings(), UpdateSettings(), reference, HeadingState(), aided, TICK, mag_body, wrong, 0.05)
    assert h.diagnostic.reason != "dip", h.diagnostic
    plain = GravityState(tilt_known=True, converged=True, measured_body=np.array([0.0, 0.0, 1.0]), measured_world=DOWN_NED)
    h = update_heading(MagSettings(), UpdateSettings(), reference, HeadingState(), plain, TICK, mag_body, TRUTH, 0.05)
    assert h.diagnostic.reason == "dip"
    field = np.array(FIELD_NED) / np.linalg.norm(FIELD_NED)
    lift = quat.to_matrix(TRUTH) @ np.array([0.0, 0.0, 1.0])
    off = math.degrees(math.acos(field @ lift) - math.acos(field @ DOWN_NED))
    assert off == pytest.approx(12.7, abs=0.05) and off > MagSettings().dip_gate_deg


def _fix(t_ns: int, vel, accuracy_m_s: float) -> GnssSample:
    return GnssSample(t_ns, 3, tuple(vel), False, accuracy_m_s, None, None, None, False, SourceId("mavlink", 1, 1, 0))


def _paired(velocities, accuracy_m_s: float) -> VelocityState:
    state = VelocityState()
    for k, vel in enumerate(velocities):
        placed = 1_000_000_000 + k * 100_000_000
        state = track_velocity(GnssSettings(), AccelSettings(), UpdateSettings(), state, [(_fix(placed, vel, accuracy_m_s), placed)],
                               GravityState(), None, placed, 10_000_000, quat.IDENTITY.copy(), 90.0, 90.0, 3.0, False).state
    return state


def test_the_pairs_of_fixes_are_what_raw_readings_measure_until_they_are_old():
    """Two fixes 0.1 s apart (no vertical velocity), 0.05 m/s accurate, differ by (0, 0.5, 0) m/s: ``a`` = (0, 5, 0)
    m/s^2, ``g e_z - a`` = (0, -5, g), its noise ``sqrt(2) 0.05 / 0.1`` = 0.71 m/s^2, measured at the middle of the
    pair (0.15 s latency); aiding or not (no accelerometer history yet). Past ``gnss.max_age_s`` plus the latency it
    is not used; nor an acceleration within three times its noise (0.3 m/s receivers: 4.2 m/s^2)."""
    params, accel = GnssSettings(), AccelSettings()
    state = _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0)], 0.05)
    world = raw_world(params, accel, state, 1_100_000_000)
    np.testing.assert_allclose(world.vector_m_s2, [0.0, -5.0, G], atol=1e-9)
    assert world.noise_m_s2 == pytest.approx(math.sqrt(2.0) * 0.05 / 0.1, rel=1e-9)
    assert state.recent_ns == 1_000_000_000 + 50_000_000 - 150_000_000
    assert raw_world(params, accel, state, state.recent_ns + 1_150_000_001) is None
    assert raw_world(GnssSettings(enabled=False), accel, state, 1_100_000_000) is None
    assert raw_world(params, accel, _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0)], 0.3), 1_100_000_000) is None
    # a third fix: the low-pass over gnss.raw_lowpass_s (alpha = 0.1 / 0.3), toward a = (0, 2, 0)
    three = _paired([(10.0, 0.0, 0.0), (10.0, 0.5, 0.0), (10.0, 0.7, 0.0)], 0.05)
    np.testing.assert_allclose(three.recent_world_m_s2, [0.0, -5.0 + (1.0 / 3.0) * (5.0 - 2.0), G], atol=1e-9)


def test_without_a_heading_measurement_the_tilt_alone_decides_convergence():
    """6-D (the magnetometer off): the heading is never known, so the whole doubt never falls below
    ``updates.converged_deg`` and raw readings, linear accelerations and all, would be taken for ever; the tilt's
    doubt decides instead. With a heading measured the whole doubt does, as before."""
    level = GravityState(tilt_known=True)
    unsure_heading = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=90.0, prior_tilt_doubt_deg=2.0)
    at_rest = np.array([0.0, 0.0, -G])
    six_d = update_gravity(AccelSettings(), UpdateSettings(), level, unsure_heading, at_rest, 3.0, quat.IDENTITY.copy(), 0.01,
                           heading_measured=False)
    assert six_d.state.converged and six_d.state.accel_lp_m_s2 is not None
    nine_d = update_gravity(AccelSettings(), UpdateSettings(), level, unsure_heading, at_rest, 3.0, quat.IDENTITY.copy(), 0.01)
    assert not nine_d.state.converged and nine_d.state.accel_lp_m_s2 is None


@pytest.mark.parametrize("interval_s, factor", [(0.0025, 2.0), (0.005, math.sqrt(2.0)), (0.01, 1.0), (0.1, 1.0)])
def test_a_fast_start_reading_counts_per_ten_milliseconds(interval_s, factor):
    """A raw reading's sigma is ``accel.sigma_rad`` per ``updates.fast_start_interval_s`` (10 ms) of readings:
    readings every 2.5 / 5 ms are 2 / sqrt(2) times as noisy (the same information per second, ``1 / (sigma^2 T)``),
    sparser ones as given. Level and at rest, at a cold start (the prior's doubt above ``updates.converged_deg``)."""
    cold = TickContext(dt_s=0.01, process_variance_rad2=1e-6, prior_doubt_deg=60.0, prior_tilt_doubt_deg=50.0)
    reading = update_gravity(AccelSettings(), UpdateSettings(), GravityState(), cold, np.array([0.0, 0.0, -G]), 3.0,
                             quat.IDENTITY.copy(), interval_s)
    assert not reading.state.converged and reading.apply_now
    assert reading.diagnostic.sigma_deg == pytest.approx(math.degrees(AccelSettings().sigma_rad * factor), rel=1e-12)
