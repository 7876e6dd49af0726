"""The reference field: configured, or the World Magnetic Model's at the first GNSS fix's position and date.

The expected field is computed independently with ``core.earth_field`` (pygeomag's WMM, itself checked
against NOAA's published test values in tests/test_earth_field.py) at the fix's position and the date the
rules give; the declination with ``core.earth_field.declination_deg``.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np
import pytest

from core import quaternion as quat
from core.earth_field import decimal_year, declination_deg, field_ned_gauss
from drivers.samples import GnssSample, ImuSample, SourceId
from fuser.config import FuserConfig
from fuser.loop import FusionLoop
from fusion_inputs import GRAVITY_M_S2

SRC = SourceId("mavlink", 1, 1, 0)
CANBERRA = (-35.3632621, 149.1652374, 584.0)  # ArduPilot SITL's home: declination about +12 deg, the field points up
NEW_YORK = (40.7, -74.0, 10.0)  # declination about -12.5 deg, and a norm and dip within the fallback's gates
MARCH_2027_NS = int(datetime(2027, 3, 15, 12, 0, tzinfo=timezone.utc).timestamp()) * 1_000_000_000
FALLBACK = (0.21, 0.0, 0.43)


def _fly(config: FuserConfig, field_read: tuple, fix_at_s: float | None, fix_t_ns=lambda t: t, t0_ns: int = 5_000_000_000,
         seconds: float = 6.0, yaw_deg: float = 30.0, where: tuple = CANBERRA):
    """A vehicle at rest, yawed ``yaw_deg`` from north, whose magnetometer reads ``field_read`` (NED); 200 Hz IMU with
    its magnetometer; one GNSS fix a second from ``fix_at_s`` on (stamped ``fix_t_ns(t)``). Returns the loop and
    its estimates."""
    q = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), math.radians(yaw_deg))
    accel = tuple(quat.rotate(quat.conjugate(q), [0.0, 0.0, -GRAVITY_M_S2]))
    mag = tuple(quat.rotate(quat.conjugate(q), np.asarray(field_read)))
    loop = FusionLoop(config)
    estimates = []
    for k in range(int(seconds * 200)):
        t = t0_ns + k * 5_000_000
        samples = [ImuSample(t, (0.0, 0.0, 0.0), accel, mag, SRC)]
        if fix_at_s is not None and k % 200 == 0 and k >= fix_at_s * 200:
            samples.append(GnssSample(fix_t_ns(t), 3, (0.0, 0.0, 0.0), True, 0.1, *where, False, SRC))
        estimates += loop.advance(t + 1_000_000)
        for s in samples:
            loop.push(s, t + 1_000_000)
    return loop, estimates + loop.flush()


def _field_diagnostics(estimates) -> list[dict]:
    return [d for e in estimates for d in e.diagnostics if d["update"] == "mag_field"]


def test_the_first_fix_gives_the_wmm_field_at_its_position_and_utc_date():
    """A fix stamped in Unix time (GPS_RAW_INT's time_usec from an autopilot with a fix): its date is the WMM's."""
    first_fix_ns = MARCH_2027_NS + 5_000_000_000 + 2_000_000_000
    expected = field_ned_gauss(*CANBERRA, decimal_year(first_fix_ns * 1e-9))
    loop, estimates = _fly(FuserConfig(), expected, 2.0, fix_t_ns=lambda t: MARCH_2027_NS + t)
    field = loop.model.state.field
    assert field.source == "wmm" and field.date_source == "gnss"
    assert field.field_ned_gauss == pytest.approx(expected, abs=1e-12)
    assert field.position == pytest.approx(CANBERRA) and field.decimal_year == pytest.approx(2027.2, abs=0.01)
    first, wmm = _field_diagnostics(estimates)  # the fallback at the start, the WMM's from the fix on
    assert first["reason"] == "fallback" and first["field_ned_gauss"] == list(FALLBACK)
    assert wmm["reason"] == "wmm" and wmm["field_ned_gauss"] == pytest.approx(list(expected), abs=1e-12)
    assert wmm["declination_deg"] == pytest.approx(declination_deg(*CANBERRA, wmm["decimal_year"]), abs=1e-6)
    assert loop.diagnostics()["mag_field"]["reason"] == "wmm"  # the status keeps it


def test_a_boot_clock_fix_takes_the_date_of_the_loops_unix_timeline():
    """A fix on the vehicle's boot clock, received live (the loop's timeline is Unix time): the host's date."""
    loop, _ = _fly(FuserConfig(), FALLBACK, 1.0, fix_t_ns=lambda t: t - MARCH_2027_NS + 90_000_000_000, t0_ns=MARCH_2027_NS)
    field = loop.model.state.field
    tick = MARCH_2027_NS + 1_000_000_000 + 1_000_000  # the first fix's tick: received 1 ms after it was sent, at 1 s
    assert field.date_source == "timeline" and field.decimal_year == pytest.approx(decimal_year(tick * 1e-9), abs=1e-6)
    assert field.field_ned_gauss == pytest.approx(field_ned_gauss(*CANBERRA, decimal_year(tick * 1e-9)), abs=1e-12)


def test_without_any_unix_time_the_undated_default_and_a_set_date():
    loop, _ = _fly(FuserConfig(), FALLBACK, 1.0)  # boot clocks everywhere (a simulated flight at full speed)
    assert loop.model.state.field.date_source == "undated" and loop.model.state.field.decimal_year == 2026.5
    assert loop.model.state.field.field_ned_gauss == pytest.approx(field_ned_gauss(*CANBERRA, 2026.5), abs=1e-12)
    loop, _ = _fly(FuserConfig().replace(mag={"wmm_decimal_year": 2012.0}), FALLBACK, 1.0)
    assert loop.model.state.field.date_source == "config"
    assert loop.model.state.field.field_ned_gauss == pytest.approx(field_ned_gauss(*CANBERRA, 2012.0), abs=1e-12)


def test_a_configured_field_wins():
    configured = (0.2, 0.05, -0.5)
    loop, estimates = _fly(FuserConfig().replace(mag={"field_ned_gauss": configured}), configured, 1.0)
    assert loop.model.state.field.source == "config" and loop.model.state.field.field_ned_gauss == configured
    (only,) = _field_diagnostics(estimates)
    assert only["reason"] == "config"


def test_without_gnss_the_fallback_is_reported_once():
    loop, estimates = _fly(FuserConfig(), FALLBACK, None)
    assert loop.model.state.field.source == "fallback"
    assert [d["reason"] for d in _field_diagnostics(estimates)] == ["fallback"]


def _yaw_deg(q) -> float:
    forward = quat.rotate(np.asarray(q), [1.0, 0.0, 0.0])
    return math.degrees(math.atan2(forward[1], forward[0]))


def test_the_heading_is_turned_with_the_references_north():
    """The magnetometer reads the WMM's field (declination -12.5 deg in New York), the estimate's heading has
    converged against the fallback's north (no declination): 12.5 deg off true. When the fix gives the WMM's field
    the heading is turned by the declination at once, true north from then on (as the autopilot reports it)."""
    wmm = field_ned_gauss(*NEW_YORK, 2026.5)
    decl = declination_deg(*NEW_YORK, 2026.5)
    loop, estimates = _fly(FuserConfig(), wmm, 4.0, seconds=4.2, where=NEW_YORK)
    fix_tick = next(e.t_ns for e in estimates if any(d["update"] == "mag_field" and d["reason"] == "wmm" for d in e.diagnostics))
    before = next(e for e in reversed(estimates) if e.t_ns < fix_tick)
    after = next(e for e in estimates if e.t_ns == fix_tick)
    assert _yaw_deg(before.q_wxyz) == pytest.approx(30.0 - decl, abs=1.0)  # magnetic: the fallback has no declination
    assert _yaw_deg(after.q_wxyz) - _yaw_deg(before.q_wxyz) == pytest.approx(decl, abs=0.2)
    assert _yaw_deg(estimates[-1].q_wxyz) == pytest.approx(30.0, abs=0.5)
    assert decl < -10.0
