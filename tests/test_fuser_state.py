"""The model's persistent state as one value: read, set into another model, reset; the continuation is identical."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.samples import SourceId
from drivers.sim import SimConfig, samples, simulate
from fuser.config import FuserConfig
from fuser.model import FilterState, FusionModel, TickInput
from fuser.model.state import STATE, FieldState, knot_capacity
from model_records import field_bytes

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


def _bytes(state: FilterState) -> tuple:
    """Everything ``state`` holds, its arrays as bytes (read by numpy, not by the state's own code; the record's
    fields without its padding)."""
    return field_bytes(state.record), state.knots_ns.tobytes(), state.knots.tobytes(), state.field, state.imu_slots, state.gnss_slots


def _scribble(state: FilterState) -> None:
    """Overwrite every number ``state`` holds."""
    state.record.view(np.uint8)[...] = 0xAB
    state.knots_ns[...] = -1
    state.knots[...] = np.nan


def test_a_state_read_is_a_copy_of_its_own():
    """Two reads are two independent values: writing into one (every byte of it) changes neither the other nor the model."""
    model = FusionModel(FuserConfig())
    _run(model, TICKS[:200])
    a, b = model.state, model.state
    held = _bytes(b)
    assert _bytes(a) == held
    _scribble(a)
    assert _bytes(a) != held  # the premise: the scribble reached every array
    assert _bytes(b) == held and _bytes(model.state) == held


def test_a_state_set_is_copied_in():
    """The model keeps a copy of the state it is given: the caller's value written over afterwards does not reach it,
    and the model continues as the one it was read from."""
    first = FusionModel(FuserConfig())
    _run(first, TICKS[:200])
    saved = first.state
    held = _bytes(saved)
    model = FusionModel(FuserConfig())
    model.state = saved
    _scribble(saved)
    assert _bytes(model.state) == held
    assert _same(_run(model, TICKS[200:300]), _run(first, TICKS[200:300]))


def test_a_state_of_another_loop_rate_is_refused():
    """The accelerometer's history for the GNSS pairs is a ring sized by the loop rate
    (:func:`fuser.model.state.knot_capacity`): a state of a model at another rate does not fit, and is refused
    before anything of it is taken."""
    model = FusionModel(FuserConfig())
    _run(model, TICKS[:100])
    held = _bytes(model.state)
    other = FusionModel(FuserConfig(rate_hz=50.0)).state
    assert knot_capacity(FuserConfig(rate_hz=50.0)) != knot_capacity(FuserConfig())  # the premise: the rings differ
    with pytest.raises(ValueError, match="loop rate"):
        model.state = other
    assert _bytes(model.state) == held


def test_reset_forgets_everything_a_flight_taught():
    """After a reset the state is a new model's, byte for byte: the record, the accelerometer's history, the field
    and which IMU and GNSS stream each slot held."""
    model = FusionModel(FuserConfig())
    _run(model, TICKS[:450])
    fresh = _bytes(FusionModel(FuserConfig()).state)
    flown = model.state
    assert field_bytes(flown.record) != fresh[0] and flown.imu_slots != ()  # the premise: the flight changed the state
    model.reset()
    assert _bytes(model.state) == fresh


def test_a_copy_carries_every_field_of_the_state():
    """Replaces the check of ``BiasState.with_estimate``, which built a state field by field (not by
    ``dataclasses.replace``) and had to carry every field it was not given. The state is one record now, each part
    changed in place by its own module (tests/test_fuser_state_carry.py); what is still built field by field is
    :meth:`FilterState.copy` (every read and set of :attr:`FusionModel.state`): every field must come through, the
    arrays as copies of their own, including any field added later (the field set is pinned here)."""
    names = [f.name for f in dataclasses.fields(FilterState)]
    assert names == ["record", "knots_ns", "knots", "field", "imu_slots", "gnss_slots"]
    rng = np.random.default_rng(4)
    capacity = knot_capacity(FuserConfig())
    record = np.zeros(1, STATE)
    record.view(np.uint8)[...] = rng.integers(0, 256, record.nbytes, dtype=np.uint8)
    source = SourceId("mavlink", 1, 1, 2)
    state = FilterState(record, rng.integers(1, 10**12, capacity), rng.normal(size=(capacity, 6)),
                        FieldState((0.2, 0.01, 0.4), "wmm", (47.0, 8.0, 400.0), 2025.5, "gnss", True), (source,), ((source, True),))
    copy = state.copy()
    for name in names:
        x, y = getattr(state, name), getattr(copy, name)
        if isinstance(x, np.ndarray):
            assert not np.shares_memory(x, y) and x.dtype == y.dtype and x.shape == y.shape, name
            assert (field_bytes(x) == field_bytes(y)) if x.dtype.names else (x.tobytes() == y.tobytes()), name
        else:
            assert y == x, name
    _scribble(copy)
    assert field_bytes(state.record) != field_bytes(copy.record) and not np.isnan(state.knots).any()
