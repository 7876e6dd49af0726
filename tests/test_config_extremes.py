"""Every numeric setting at either end of its allowed range replays a flight: no exception, every estimate written,
no tick skipped.

A configuration is input: "no NaN, overflow or exception for any valid input" holds for every value a setting's
:class:`fuser.config.Range` lets through. Before the ranges were closed, a loop rate of 1e9 Hz asked numpy for 51 GiB,
a gyro noise of 1e300 or an accelerometer sigma of 1e-300 divided by zero inside the compiled tick, a gate of 1e-300
sigma wrote an infinite test ratio that stopped the recorder, a model error of 1e300 deg left every estimate unwritten
(NaN), and a wait of 20 s dropped the first ticks of a short log: 23 of these cases failed on that code, where
the ranges were open (``gt=0``: tested at 5e-324) or unbounded (1e300).

The flight: the first 5 s of ``logs/sim_aggressive.mcap`` (IMU with magnetometer at 200 Hz, the autopilot's attitude,
GNSS velocity and position), so that every update runs; the autopilot's attitude is fused (``attitude.mode =
"always"``) for the attitude group's settings. An open bound (``gt``, ``lt``) is tested at the next float inside it;
a setting without an upper bound at 1e300 (an integer at 10**18).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path

import pytest

from fuser.config import FuserConfig, Range, load_config
from fuser.record import McapRecorder, read_log
from fuser.replay import replay

LOG = Path(__file__).resolve().parent.parent / "logs" / "sim_aggressive.mcap"
SECONDS = 5.0


def _numeric_settings(cls: type = FuserConfig, prefix: str = "") -> list[tuple[str, type, Range]]:
    """``(dotted key, int or float, its Range)`` of every numeric setting, groups included."""
    out = []
    hints = typing.get_type_hints(cls, include_extras=True)
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            out += _numeric_settings(hint, f"{prefix}{f.name}.")
        elif typing.get_origin(hint) is typing.Annotated:
            base, *extra = typing.get_args(hint)
            bounds = next((e for e in extra if isinstance(e, Range)), None)
            if bounds is not None and base in (int, float):
                out.append((prefix + f.name, base, bounds))
    return out


def _extremes(kind: type, bounds: Range) -> list[float | int]:
    """The least and the greatest value ``bounds`` allow (an unbounded end: 1e300, or 10**18 for an integer)."""
    if kind is int:
        low = bounds.ge if bounds.ge is not None else bounds.gt + 1
        return [int(low), int(bounds.le) if bounds.le is not None else 10**18]
    low = bounds.ge if bounds.ge is not None else math.nextafter(bounds.gt, math.inf)
    high = bounds.le if bounds.le is not None else math.nextafter(bounds.lt, -math.inf) if bounds.lt is not None else 1e300
    return [float(low), float(high)]


COMPANIONS: dict[str, dict[str, typing.Any]] = {
    "bias.initial_sigma_rad_s": {"bias.floor_sigma_rad_s": 0.0},  # the floor may not exceed it
    "bias.floor_sigma_rad_s": {"bias.initial_sigma_rad_s": 1.0},
}
"""Settings bound by a rule between fields (``_validate``): set with another that lets each end through."""

CASES = [(key, value) for key, kind, bounds in _numeric_settings() for value in _extremes(kind, bounds)]


def test_the_cases_cover_the_settings():
    """The walk over the settings finds them all (a group the walk missed would go untested)."""
    keys = {key for key, _ in CASES}
    assert {"rate_hz", "latency_ms", "gyro.noise_rad_s_rt_hz", "accel.sigma_rad", "updates.innovation_gate_sigma",
            "model_error.tilt_deg", "latency.window_s", "imu_check.frozen_samples", "gnss.max_age_s"} <= keys
    assert len(keys) >= 70


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    """The first :data:`SECONDS` of the aggressive flight's inputs, as a log of their own."""
    source = read_log(LOG)
    inputs = source.inputs()
    end_ns = inputs[0][1] + round(SECONDS * 1e9)
    path = tmp_path_factory.mktemp("extremes") / "aggressive_5s.mcap"
    with McapRecorder(path, metadata=source.metadata["bingham_fuser"]) as rec:
        for sample, receive_ns in inputs:
            if receive_ns <= end_ns:
                rec.write_sample(sample, receive_ns)
    return path


@pytest.mark.parametrize(("key", "value"), CASES, ids=[f"{k}={v:g}" for k, v in CASES])
def test_a_setting_at_the_end_of_its_range_replays_the_flight(flight, tmp_path, key, value):
    overrides: dict[str, typing.Any] = {key: value, **COMPANIONS.get(key, {})}
    if key.startswith("attitude."):
        overrides["attitude.mode"] = "always"
    config = load_config(None, overrides)
    summary = replay(flight, tmp_path / "out.mcap", config, progress=None)
    assert summary.not_recorded == {}, "estimates or diagnostics the recorder could not write (not finite)"
    assert "ticks_skipped" not in summary.counters
    ticks = summary.counters["ticks"]
    assert abs(ticks - SECONDS * config.rate_hz) <= 2 + 0.01 * SECONDS * config.rate_hz
    estimates = read_log(tmp_path / "out.mcap").estimates()
    assert len(estimates) == summary.estimates >= ticks
    for est in estimates:
        assert math.isclose(math.hypot(*est.q_wxyz), 1.0, abs_tol=1e-9)
        assert 0.0 <= est.uncertainty_deg <= 180.0


def test_a_value_beyond_a_range_is_refused_naming_the_setting_and_its_bound():
    with pytest.raises(ValueError, match=r"fuser\.rate_hz must be <= 2000 Hz, got 1000000000\.0"):
        load_config(None, {"rate_hz": 1e9})
    with pytest.raises(ValueError, match=r"fuser\.accel\.sigma_rad must be >= 1e-05 rad"):
        load_config(None, {"accel.sigma_rad": 1e-300})


def test_a_wait_longer_than_the_catch_up_limit_runs_every_tick_of_a_short_log(flight, tmp_path):
    """The replay skips a gap longer than 1000 ticks; at a 400 Hz loop a 10-s wait is 4000 periods, so the 5-s log's
    2000 ticks all came due at its end, where only the last 1000 ran (the wait is not a gap)."""
    config = load_config(None, {"rate_hz": 400.0, "latency_ms": 10_000.0})
    summary = replay(flight, tmp_path / "out.mcap", config, progress=None)
    assert "ticks_skipped" not in summary.counters
    assert abs(summary.counters["ticks"] - SECONDS * 400) <= 3
