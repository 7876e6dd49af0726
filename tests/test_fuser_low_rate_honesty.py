"""A ground station's telemetry log at ArduPilot's default stream rates (RAW_IMU, SCALED_IMU2, SCALED_IMU3 at
2.8-3.7 Hz each, on their own clocks, through a radio), flown through the simulated multirotor's aggressive
manoeuvres (24-43 s of flight time): what it is fused into, scored against the simulator's attitude that the
log's messages were made from (tests/tlog_builder.py), not against the log's 3.6-Hz ATTITUDE, which slerp cannot
follow through a flip.

Between samples 0.1-0.3 s apart the rate's path is unknown. With the configured rate walk alone (0.3 rad/s/sqrt(s))
the estimate was 54.5 deg off (RMS) in the manoeuvres while it reported 9.0, the truth inside its 90 % region on
10 % of them and 71 % over the flight (after 5 s); it stayed lost after them (3.6 deg RMS in the calm flight).
The walk the samples themselves show (the change of slope between consecutive intervals, the window's roughest
peak-held over a second, in a stream slower than 30 ms; :mod:`fuser.model.propagation`) widens it: 43.9 deg off
reporting 39.2 in the manoeuvres (59 %), 88 % over the flight, and 0.8 deg in the calm flight (100 %).

The manoeuvres' remaining misses were not the accelerometer (as this file said before) but the output predictor: over
this radio the loop waits 100-250 ms for samples in flight, and each estimate, stamped when it is published, was the
tick's state carried over that wait at the last sample's held rate with the tick's concentrations (the held rate's
walk counted to the tick's lead only): through a flip 28-77 deg off while reporting 5-15. Counting the hold's walk to
the stamp (:mod:`fuser.model.output`): 43.9 deg off reporting 59.2 (RMS), the truth inside the 90 % region on 90 %
of the manoeuvres' estimates (50 / 95 % regions: 67 / 92 %; 55 / 59 / 77 % before), 97 % over the flight, the calm
flight unchanged (0.8 deg; reported median 3.5). And the predictor was turned by the reference IMU's samples alone
(RAW_IMU's, 3.3 Hz) while the tick merges the three: in a slow stream the others' turn it too, 43.9 -> 35.8 deg RMS
in the manoeuvres (median 26.8 -> 19.3), the 90 % region 90 -> 92 %. The figures are the fixture's arrays (the
builder's seed 0), before and after each change in one checkout.
"""

from __future__ import annotations

import numpy as np
import pytest

from fuser.config import FuserConfig
from fuser.evaluate import credible_level
from fuser.record import read_log
from fuser.replay import replay
from tlog_builder import TlogShape, build_tlog, true_attitude_at

SHAPE = TlogShape()  # 120 s at telemetry rates, a reboot at 70 s, radio damage
MANOEUVRES_S = (24.0, 43.0)
AFTER_S = 5.0


@pytest.fixture(scope="module")
def fused(tmp_path_factory) -> dict[str, np.ndarray]:
    """The log fused with the defaults; per estimate after the first 5 s: its log time, error, reported
    uncertainty, and the credible level at which its region holds the truth."""
    tmp = tmp_path_factory.mktemp("low_rate")
    built = build_tlog(tmp / "telemetry.tlog", SHAPE)
    replay(built.path, tmp / "fused.mcap", FuserConfig(), progress=None)
    est = [e for e in read_log(tmp / "fused.mcap").estimates() if e.sensor_t_ns is not None]
    q_true, t = true_attitude_at(built, SHAPE, np.array([e.sensor_t_ns for e in est]))
    keep = t > AFTER_S
    q = np.array([e.q_wxyz for e in est])[keep]
    dot = np.abs(np.sum(q * q_true[keep], axis=1))
    return {
        "t": t[keep],
        "error_deg": np.degrees(2.0 * np.arccos(np.clip(dot, 0.0, 1.0))),
        "reported_deg": np.array([e.uncertainty_deg for e in est])[keep],
        "level": credible_level(np.array([e.M for e in est])[keep], np.array([e.Z for e in est])[keep], q_true[keep]),
    }


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def _manoeuvres(f: dict[str, np.ndarray]) -> np.ndarray:
    return (f["t"] >= MANOEUVRES_S[0]) & (f["t"] < MANOEUVRES_S[1])


def test_over_the_flight_the_90_percent_region_holds_the_truth_at_least_85_percent_of_the_time(fused):
    assert np.mean(fused["level"] <= 0.9) >= 0.85, np.mean(fused["level"] <= 0.9)


def test_in_the_manoeuvres_the_reported_uncertainty_is_within_a_factor_2_of_the_error(fused):
    m = _manoeuvres(fused)
    assert m.sum() > 1000
    ratio = _rms(fused["reported_deg"][m]) / _rms(fused["error_deg"][m])
    assert 0.5 < ratio < 2.0, (ratio, _rms(fused["error_deg"][m]))


def test_in_the_manoeuvres_every_imus_samples_turn_the_published_estimate(fused):
    """35.8 deg RMS; 43.9 while only the reference IMU's samples turned the output predictor (docstring)."""
    assert _rms(fused["error_deg"][_manoeuvres(fused)]) < 40.0


def test_out_of_the_manoeuvres_it_follows_the_vehicle(fused):
    """The roughest interval is let go a window after the manoeuvre: the calm flight is scored as before."""
    calm = ~_manoeuvres(fused)
    assert _rms(fused["error_deg"][calm]) < 5.0
    assert np.mean(fused["level"][calm] <= 0.9) >= 0.85


def test_in_the_manoeuvres_the_90_percent_region_holds_the_truth_at_least_85_percent_of_the_time(fused):
    m = _manoeuvres(fused)
    assert np.mean(fused["level"][m] <= 0.9) >= 0.85, np.mean(fused["level"][m] <= 0.9)
