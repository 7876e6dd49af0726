"""The magnetometer's reference field: configured, or the World Magnetic Model's at the vehicle's GNSS position.

A field given in ``[fuser.mag] field_ned_gauss`` always wins (source
``"config"``). Otherwise (*not configured*, the default) the reference is
``mag.fallback_field_ned_gauss`` (source ``"fallback"``: a mid-latitude field
without declination, the heading then magnetic) until the first GNSS fix with
a position arrives; from then on it is the WMM's field at that position and
date (source ``"wmm"``; :mod:`core.earth_field`, NOAA/BGS WMM2010-2025 through
``pygeomag``), north-east-down *with the declination*: the heading is then
relative to true north, as ArduPilot's EKF3 and PX4's EKF2 report theirs
(both take the declination from the same model at the GNSS position), so
the autopilot's heading and ours agree rather than differ by the declination.
The field is evaluated once, at the first position (it changes by about
0.01 deg of declination per km at mid latitudes; a flight does not leave its
model cell).

The date: ``mag.wmm_decimal_year`` if set; else the fix's own time when it
is a Unix time (GPS_RAW_INT and GPS_INPUT carry UTC from an autopilot with a
fix, ``t_ns`` from 2001 on); else the loop's timeline when it is a Unix time
(a live run's host clock, a recording's receive times in replay); else
``mag.wmm_undated_decimal_year`` (a simulated flight on its own clock). Every
time comes from the input, none from a clock here: a replay gives the same
field.

When the WMM's field replaces the fallback, the heading the magnetometer has
measured so far was measured against the fallback's north: the estimate is
turned about world down by the change of the reference's heading (the
declination, the fallback having none; :func:`heading_change_rad`, which the
tick (:func:`fuser.model.fusion.tick`) turns its prediction by,
``q -> Rz(change) (x) q``), so the evidence it holds is re-expressed, not contradicted. Fused instead, the
sudden heading innovation would be taken for gyro drift by the bias
feedback (measured: a 0.5 deg/s z bias learnt from a 3.6 deg declination).

The field in use, its source and where it was evaluated are reported as a
``mag_field`` diagnostic on the first tick and whenever they change (so the
live status's latest diagnostics always hold it), and logged.
"""

from __future__ import annotations

import logging
import math
from typing import Iterable

from core import earth_field
from drivers.samples import GnssSample
from fuser.config import MagSettings
from fuser.model.diagnostics import UpdateDiagnostic
from fuser.model.state import DateSource, FieldState

__all__ = ["UNIX_MIN_NS", "heading_change_rad", "update_field"]

log = logging.getLogger(__name__)

UNIX_MIN_NS = 10**18
"""A time this large (September 2001 on) is Unix time, not time since boot (as MAVLink's ``time_usec`` rule)."""
FIX_2D = 2


def _date(params: MagSettings, fix_ns: int, tick_ns: int) -> tuple[float, DateSource]:
    if params.wmm_decimal_year is not None:
        return params.wmm_decimal_year, "config"
    for t_ns, source in ((fix_ns, "gnss"), (tick_ns, "timeline")):
        if t_ns >= UNIX_MIN_NS:
            year = earth_field.decimal_year(t_ns * 1e-9)
            if earth_field.FIRST_YEAR <= year < earth_field.LAST_YEAR:
                return year, source  # type: ignore[return-value]
    return params.wmm_undated_decimal_year, "undated"


def update_field(params: MagSettings, state: FieldState, fixes: Iterable[GnssSample], tick_ns: int) -> tuple[FieldState, UpdateDiagnostic | None]:
    """The field after this tick's GNSS fixes (the WMM's at the first position, if not configured), and its
    diagnostic when it is new."""
    if state.source == "fallback" and state.position is None:
        fix = next((g for g in fixes if g.fix_type >= FIX_2D and g.lat_deg is not None and g.lon_deg is not None), None)
        if fix is not None:
            year, date_source = _date(params, fix.t_ns, tick_ns)
            alt = 0.0 if fix.alt_m is None else fix.alt_m
            try:
                field = earth_field.field_ned_gauss(fix.lat_deg, fix.lon_deg, alt, year)  # type: ignore[arg-type]
            except ValueError as exc:  # outside the model's range (an altitude beyond 850 km): keep the fallback
                log.warning("no WMM field at the GNSS fix (%s): the fallback field stays the reference", exc)
                tried = FieldState(state.field_ned_gauss, state.source, (fix.lat_deg, fix.lon_deg, alt), year, date_source, True)  # type: ignore[arg-type]
                return tried, UpdateDiagnostic("mag_field", "gated", "out_of_range")
            state = FieldState(field, "wmm", (fix.lat_deg, fix.lon_deg, alt), year, date_source)  # type: ignore[arg-type]
            log.info("reference field from the WMM at %.5f, %.5f, %.0f m, %.2f (%s date): N %.4f E %.4f D %.4f G, declination %.2f deg",
                     fix.lat_deg, fix.lon_deg, alt, year, date_source, *field, math.degrees(math.atan2(field[1], field[0])))
    if state.reported:
        return state, None
    reported = FieldState(state.field_ned_gauss, state.source, state.position, state.decimal_year, state.date_source, True)
    return reported, reported.diagnostic()


def heading_change_rad(before: FieldState, after: FieldState) -> float:
    """How far north turned between two reference fields (the change of their horizontal direction, rad)."""
    (n0, e0, _), (n1, e1, _) = before.field_ned_gauss, after.field_ned_gauss
    return math.remainder(math.atan2(e1, n1) - math.atan2(e0, n0), 2.0 * math.pi)
