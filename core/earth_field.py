"""The earth's magnetic field at a position and date, from the World Magnetic Model (WMM).

The reference field a magnetometer heading is measured against: north, east,
down (NED) in gauss, *declination included*, so that a heading referenced to it
is relative to true north (as ArduPilot's and PX4's estimators report it).

The model is NOAA/BGS's WMM (Chulliat et al., "The US/UK World Magnetic Model
for 2025-2030", NOAA Technical Report, 2024), evaluated by ``pygeomag``, a
pure-Python port of NOAA's reference C code that ships the WMM2010, 2015v2,
2020 and 2025 coefficient files; the file whose five-year life span holds the
date is used, so logs from 2010 to 2029 get the model of their day.
``tests/test_earth_field.py`` checks it against the test values NOAA publishes
with WMM2025.

Arguments: geodetic latitude and longitude (WGS84, degrees), altitude in metres
(the WMM takes height above the WGS84 ellipsoid; a GNSS altitude above mean sea
level differs from it by the geoid undulation, at most about 100 m, which moves
the field by under 3 nT, far below the model's own 140 nT error), and the date
as a decimal year (2026.5 is the first of July 2026): :func:`decimal_year` makes
one from a Unix time, e.g. a GNSS fix's UTC time. Near the magnetic poles
(horizontal field under 2000 nT, the WMM's "blackout zone") the declination is
ill-defined and the heading it gives is not trustworthy; the field is still
returned.

This module lives in ``core`` because both the simulators (``drivers/``) and
the fuser use it, and ``drivers`` must not import ``fuser``.
"""

from __future__ import annotations

import calendar
import math
from datetime import datetime, timezone
from functools import lru_cache

from pygeomag import GeoMag

__all__ = ["FIRST_YEAR", "LAST_YEAR", "decimal_year", "declination_deg", "field_ned_gauss"]

NT_PER_GAUSS = 1e5
FIRST_YEAR = 2010.0
"""Earliest date covered (WMM2010's epoch)."""
LAST_YEAR = 2030.0
"""End of WMM2025's life span (exclusive)."""
_MIN_ALT_M, _MAX_ALT_M = -1_000.0, 850_000.0
"""The WMM's validity in altitude: 1 km below the ellipsoid to 850 km above."""


def _check(lat_deg: float, lon_deg: float, alt_m: float, decimal_year: float) -> tuple[float, float, float, float]:
    """The arguments as floats, or ValueError naming the first one out of the model's range."""
    values = {"lat_deg": lat_deg, "lon_deg": lon_deg, "alt_m": alt_m, "decimal_year": decimal_year}
    for name, value in values.items():
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
    if not -90.0 <= lat_deg <= 90.0:
        raise ValueError(f"lat_deg must be in [-90, 90], got {lat_deg}")
    if not -180.0 <= lon_deg <= 360.0:
        raise ValueError(f"lon_deg must be in [-180, 360], got {lon_deg}")
    if not _MIN_ALT_M <= alt_m <= _MAX_ALT_M:
        raise ValueError(f"alt_m must be in [{_MIN_ALT_M:g}, {_MAX_ALT_M:g}] (the WMM's range), got {alt_m}")
    if not FIRST_YEAR <= decimal_year < LAST_YEAR:
        raise ValueError(f"decimal_year must be in [{FIRST_YEAR:g}, {LAST_YEAR:g}) (WMM2010 to WMM2025), got {decimal_year}")
    lon = lon_deg - 360.0 if lon_deg > 180.0 else lon_deg
    return float(lat_deg), float(lon), float(alt_m), float(decimal_year)


@lru_cache(maxsize=8)
def _model(epoch: int) -> GeoMag:
    """The WMM of the five-year life span starting at ``epoch`` (coefficients read once)."""
    return GeoMag(base_year=epoch)


def _wmm(lat_deg: float, lon_deg: float, alt_m: float, decimal_year: float):
    lat, lon, alt, year = _check(lat_deg, lon_deg, alt_m, decimal_year)
    epoch = 5 * int(year // 5)
    return _model(epoch).calculate(glat=lat, glon=lon, alt=alt / 1000.0, time=year)


def field_ned_gauss(lat_deg: float, lon_deg: float, alt_m: float, decimal_year: float) -> tuple[float, float, float]:
    """The WMM main field (north, east, down) in gauss at a geodetic position and date.

    North is true (geographic) north: the east component carries the declination.
    Raises ValueError for an argument outside the model's range.
    """
    r = _wmm(lat_deg, lon_deg, alt_m, decimal_year)
    return (r.x / NT_PER_GAUSS, r.y / NT_PER_GAUSS, r.z / NT_PER_GAUSS)


def declination_deg(lat_deg: float, lon_deg: float, alt_m: float, decimal_year: float) -> float:
    """Magnetic declination (degrees, east of true north positive) at a geodetic position and date."""
    return float(_wmm(lat_deg, lon_deg, alt_m, decimal_year).d)


def decimal_year(unix_time_s: float) -> float:
    """A Unix time (seconds since 1970-01-01 UTC) as a decimal year: year + elapsed fraction of that year."""
    if not math.isfinite(unix_time_s):
        raise ValueError(f"unix_time_s must be finite, got {unix_time_s!r}")
    year = datetime.fromtimestamp(unix_time_s, tz=timezone.utc).year
    start = calendar.timegm((year, 1, 1, 0, 0, 0))
    end = calendar.timegm((year + 1, 1, 1, 0, 0, 0))
    return year + (unix_time_s - start) / (end - start)
