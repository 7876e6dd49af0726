"""The model's persistent state as one value: read, set into another model, reset; the continuation is identical."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim import SimConfig, samples, simulate
from fuser.config import FuserConfig
from fuser.model import FilterState, FusionModel, TickInput

TICK = 10_000_000


def _ticks(seconds: float = 6.0):
    """The simulator's hover-and-turns programme at 200 Hz, grouped into 10-ms ticks (the IMU's clock is the loop's)."""
    flight = simulate(SimConfig(seed=2, duration_s=seconds, imu_rate_hz=200.0))
    groups: dict[int, list] = {}
    for t, _, ss in samples(flight):
        groups.setdefault(-(-t // TICK) * TICK, []).extend(ss)
    return [TickInput(t, TICK, ss) for t, ss in sorted(groups.items())]


TICKS = _ticks()


def _run(model: FusionModel, ticks) -> list:
    return [model.step(t) for t in ticks]


def _same(a, b) -> bool:
    return all(np.array_equal(x.published.M, y.published.M) and np.array_equal(x.published.Z, y.published.Z)
               and x.uncertainty_deg == y.uncertainty_deg and x.diagnostics == y.diagnostics for x, y in zip(a, b))


@pytest.mark.parametrize("split", [1, 150, 400])
def test_a_state_set_into_a_new_model_continues_identically(split):
    config = FuserConfig()
    first = FusionModel(config)
    _run(first, TICKS[:split])
    saved = first.state
    second = FusionModel(config)
    second.state = saved
    assert _same(_run(first, TICKS[split:]), _run(second, TICKS[split:]))


def test_a_state_read_stays_what_it_was_and_can_be_set_back():
    model = FusionModel(FuserConfig())
    _run(model, TICKS[:200])
    saved = model.state
    M = saved.attitude.M.copy()
    bias = saved.bias.estimate_rad_s.copy()
    again = _run(model, TICKS[200:300])
    assert np.array_equal(saved.attitude.M, M) and np.array_equal(saved.bias.estimate_rad_s, bias)  # later ticks did not touch it
    model.state = saved
    assert _same(_run(model, TICKS[200:300]), again)


def test_reset_gives_the_start_again():
    fresh = _run(FusionModel(FuserConfig()), TICKS[:300])
    model = FusionModel(FuserConfig())
    _run(model, TICKS[:450])
    model.reset()
    assert np.all(model.state.attitude.Z == 0.0)  # uniform: no attitude known
    assert _same(_run(model, TICKS[:300]), fresh)


def test_only_a_filter_state_can_be_set():
    with pytest.raises(TypeError, match="FilterState"):
        FusionModel(FuserConfig()).state = {"attitude": None}  # type: ignore[assignment]
    assert isinstance(FusionModel(FuserConfig()).state, FilterState)


def test_a_bias_state_with_a_new_estimate_keeps_every_other_field():
    """``with_estimate`` builds the state field by field (not by ``dataclasses.replace``): every field it is not
    given must come through, including any added later."""
    import dataclasses

    from fuser.model.state import BiasState

    old = BiasState(np.array([0.1, 0.2, 0.3]), np.diag([1e-4, 2e-4, 3e-4]), np.arange(27.0).reshape(3, 3, 3),
                    np.arange(9.0).reshape(3, 3), True, 4.5)
    names = {f.name for f in dataclasses.fields(BiasState)}
    assert names == {"estimate_rad_s", "covariance_rad2_s2", "rotation_lp", "rotated_lp_rad_s", "tilt_aided", "tilt_settled_s"}
    new = old.with_estimate(np.zeros(3), np.eye(3))
    for name in names - {"estimate_rad_s", "covariance_rad2_s2"}:
        assert getattr(new, name) is getattr(old, name), name
    assert new.variance_rad2_s2 == 1.0 and old.variance_rad2_s2 == pytest.approx(2e-4, rel=1e-15)
    assert old.with_covariance(np.eye(3) * 3.0).estimate_rad_s is old.estimate_rad_s
