"""fuser/model/params.py: every setting the model reads reaches the compiled tick's parameters record with its value.

Each field of each settings group the model reads is set, alone, to a valid value other than its default
(within its :class:`fuser.config.Range`, and the group's own rules): the record must hold that value in that
field, and every other field must keep the default's (a value written to a neighbour, or dropped, fails). A
``Literal`` is the index of its value among the choices (``params.MODE_AUTO`` etc., which the compiled policy
compares), an optional value its ``has_`` flag beside it (NaN when absent). The dtype is one for every
configuration: numba compiles the tick once whatever the settings.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Literal

import numba
import numpy as np
import pytest

from fuser.config import AttitudeSettings, ExtrapolationSettings, FuserConfig, MagSettings, Range
from fuser.model import params as model_params
from fuser.model.attitude import attitude_in_use
from fuser.model.params import MODE_ALWAYS, MODE_AUTO, MODE_OFF, PARAMS_DTYPE, params_record
from model_records import part, set_fields

NOT_THE_MODELS = {"latency": "the loop's timeline (fuser.loop)", "zenoh": "a transport", "link": "a transport",
                  "ros2": "an output", "mavlink_out": "an output"}
"""The groups of :class:`FuserConfig` the model does not read, and whose they are."""
GENERAL_SETTINGS = ("rate_hz", "latency_ms")
"""The general settings the model reads (``vehicle`` and ``record`` are strings: the loop's)."""
OPTIONAL_VALUES: dict[tuple[str, str], Any] = {("mag", "field_ned_gauss"): (0.2, -0.015, 0.45), ("mag", "wmm_decimal_year"): 2021.25}
"""A value for each optional setting whose default is None."""


def _hint(cls: type, name: str) -> tuple[Any, Range | None, bool]:
    """(type, range, optional) of setting ``name`` of ``cls``, ``Annotated`` and ``None`` taken off."""
    hint = typing.get_type_hints(cls, include_extras=True)[name]
    bounds, optional = None, False
    for _ in range(3):
        if typing.get_origin(hint) is typing.Annotated:
            hint, *extra = typing.get_args(hint)
            bounds = next((e for e in extra if isinstance(e, Range)), bounds)
        elif typing.get_origin(hint) in (typing.Union, types.UnionType):
            optional = True
            (hint,) = [a for a in typing.get_args(hint) if a is not type(None)]
    return hint, bounds, optional


def _is_number_setting(cls: type, name: str) -> bool:
    """Not a string nor a list of strings: a setting the record holds."""
    kind, _, _ = _hint(cls, name)
    return kind is not str and not (typing.get_origin(kind) is tuple and str in typing.get_args(kind))


def _model_groups() -> dict[str, type]:
    """The settings groups of :class:`FuserConfig` the model reads, by field name."""
    config = FuserConfig()
    groups = {f.name: type(getattr(config, f.name)) for f in dataclasses.fields(config) if dataclasses.is_dataclass(getattr(config, f.name))}
    assert set(NOT_THE_MODELS) <= set(groups), sorted(groups)
    return {name: cls for name, cls in groups.items() if name not in NOT_THE_MODELS}


def _other_values(group: Any, name: str) -> list[Any]:
    """Valid values of setting ``name`` of the settings ``group`` other than its current one (all choices of a
    ``Literal``); each is accepted by the group's own validation."""
    cls, default = type(group), getattr(group, name)
    kind, bounds, optional = _hint(cls, name)
    if default is None:
        candidates = [OPTIONAL_VALUES[(cls.section.removeprefix("fuser."), name)]]
    elif kind is bool:
        candidates = [not default]
    elif typing.get_origin(kind) is Literal:
        candidates = [v for v in typing.get_args(kind) if v != default]
    elif typing.get_origin(kind) is tuple:
        candidates = [tuple(0.8 * x + 0.0625 for x in default)]
    elif kind is int:
        candidates = [default + 1, default - 1]
    else:
        assert kind is float, (cls, name, kind)
        low = bounds.gt if bounds and bounds.gt is not None else bounds.ge if bounds and bounds.ge is not None else -1e3
        high = bounds.lt if bounds and bounds.lt is not None else bounds.le if bounds and bounds.le is not None else 1e6
        candidates = [1.25 * default + 0.0625, 0.8 * default, 0.5 * (low + high), low + 0.001 * (high - low)]
    out = []
    for value in candidates:
        if value == default:
            continue
        try:
            dataclasses.replace(group, **{name: value})
        except ValueError:
            continue
        out.append(value)
        if typing.get_origin(kind) is not Literal:
            break
    assert out, f"no valid value for {cls.section}.{name} other than {default!r}"
    if optional and default is not None:
        out.append(None)
    return out


def _cases() -> list[tuple[str, str, Any]]:
    """(group, setting, value): every setting of every group the model reads at a value other than its default;
    the general settings as group ``""``."""
    config, cases = FuserConfig(), []
    for group_name in _model_groups():
        group = getattr(config, group_name)
        for f in dataclasses.fields(group):
            if _is_number_setting(type(group), f.name):
                cases += [(group_name, f.name, value) for value in _other_values(group, f.name)]
    cases += [("", "rate_hz", 250.0), ("", "latency_ms", 12.5)]
    return cases


CASES = _cases()


def _config(group: str, name: str, value: Any) -> FuserConfig:
    return FuserConfig().replace(**({group: {name: value}} if group else {name: value}))


def _expected(group: str, name: str, value: Any) -> Any:
    """What the record holds for ``value``: a Literal's code (its index among the choices), else the value."""
    if not group:
        return value
    kind, _, _ = _hint(type(getattr(FuserConfig(), group)), name)
    return typing.get_args(kind).index(value) if typing.get_origin(kind) is Literal else value


def _leaves(record: np.void, prefix: str = "") -> dict[str, Any]:
    """Every field of ``record`` by its dotted path, nested records opened."""
    out = {}
    for name in record.dtype.names:
        value = record[name]
        if record.dtype[name].names:
            out |= _leaves(value, f"{prefix}{name}.")
        else:
            out[f"{prefix}{name}"] = np.array(value).tolist()
    return out


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN."""
    return bool(np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True))


def test_the_record_has_every_setting_of_every_group_the_model_reads():
    """The record's groups are the model's, each with every number, flag, choice and vector of its settings
    (plus a ``has_`` flag per optional one); the general settings the model reads after them."""
    groups = _model_groups()
    assert list(PARAMS_DTYPE.names) == [*groups, *GENERAL_SETTINGS]
    for name, cls in groups.items():
        settings = [f.name for f in dataclasses.fields(cls) if _is_number_setting(cls, f.name)]
        flags = [f"has_{s}" for s in settings if _hint(cls, s)[2]]
        assert sorted(PARAMS_DTYPE[name].names) == sorted(settings + flags), name
        assert len(settings) == len(dataclasses.fields(cls)), f"{name}: a string setting the model cannot read"
        for setting in settings:  # the layout of the module docstring
            kind, _, _ = _hint(cls, setting)
            expected = {float: np.dtype("f8"), bool: np.dtype("?"), int: np.dtype("i8")}.get(kind)
            if typing.get_origin(kind) is Literal:
                expected = np.dtype("i8")
            elif typing.get_origin(kind) is tuple:
                expected = np.dtype(("f8", (len(typing.get_args(kind)),)))
            assert PARAMS_DTYPE[name][setting] == expected, (name, setting, PARAMS_DTYPE[name][setting])
        for flag in flags:
            assert PARAMS_DTYPE[name][flag] == np.dtype("?"), (name, flag)
    assert len(CASES) > 80


@pytest.mark.parametrize("group, name, value", CASES, ids=[f"{g or 'fuser'}.{n}={v}" for g, n, v in CASES])
def test_each_setting_reaches_the_record_with_its_value(group, name, value):
    default = _leaves(params_record(FuserConfig())[0])
    out = params_record(_config(group, name, value))
    assert out.shape == (1,) and out.dtype == PARAMS_DTYPE
    leaves = _leaves(out[0])
    path = f"{group}.{name}" if group else name
    flag = f"{group}.has_{name}"
    if value is None:  # absent: the flag down, the value NaN
        assert leaves[flag] is False and np.all(np.isnan(leaves[path]))
    else:
        assert _same(leaves[path], _expected(group, name, value)), (leaves[path], value)
        assert not _same(leaves[path], default[path])  # not the default's by chance
        if flag in leaves:
            assert leaves[flag] is True
    changed = {k for k in leaves if not _same(leaves[k], default[k])}
    assert changed <= {path, flag}, changed  # nothing else moved


def test_literal_codes_are_the_indices_of_the_choices():
    """``attitude.mode``'s codes are distinct and each configuration's code is its constant; every Literal
    setting's every choice has its own code (the index, as the module docstring says)."""
    assert (MODE_AUTO, MODE_ALWAYS, MODE_OFF) == (0, 1, 2)  # the order of AttitudeSettings.mode's Literal
    for mode, code in (("auto", MODE_AUTO), ("always", MODE_ALWAYS), ("off", MODE_OFF)):
        assert params_record(FuserConfig(attitude=AttitudeSettings(mode=mode)))[0]["attitude"]["mode"] == code
        assert model_params.choice(AttitudeSettings, "mode", mode) == code
    for to in ("hold_midpoint", "published", "tick"):
        code = params_record(FuserConfig(extrapolation=ExtrapolationSettings(to=to)))[0]["extrapolation"]["to"]
        assert code == ("hold_midpoint", "published", "tick").index(to)


def test_the_compiled_policy_reads_the_mode_codes():
    """:func:`fuser.model.attitude.attitude_in_use` on each mode's record: ``always`` fuses, ``off`` never,
    ``auto`` while no gyro is known or its rate is below ``auto_below_imu_hz`` (here 20 Hz: a 100 Hz IMU is not)."""
    fast = part("gyro", has_track=True)
    set_fields(fast.track, last_ns=1_000_000_000, interval_s=0.01)
    none = part("gyro")
    expected = {"always": (True, True), "off": (False, False), "auto": (False, True)}
    for mode, (with_fast_gyro, without_gyro) in expected.items():
        p = params_record(FuserConfig(attitude=AttitudeSettings(mode=mode))).view(np.recarray)[0].attitude
        assert attitude_in_use(p, fast, 1_005_000_000) is with_fast_gyro, mode
        assert attitude_in_use(p, none, 1_005_000_000) is without_gyro, mode


def test_optional_settings_carry_their_flag():
    absent = params_record(FuserConfig(mag=MagSettings()))[0]["mag"]
    assert not absent["has_field_ned_gauss"] and np.all(np.isnan(absent["field_ned_gauss"]))
    assert not absent["has_wmm_decimal_year"] and math.isnan(absent["wmm_decimal_year"])
    given = params_record(FuserConfig(mag=MagSettings(field_ned_gauss=(0.2, -0.015, 0.45), wmm_decimal_year=2021.25)))[0]["mag"]
    assert given["has_field_ned_gauss"] and given["field_ned_gauss"].tolist() == [0.2, -0.015, 0.45]
    assert given["has_wmm_decimal_year"] and given["wmm_decimal_year"] == 2021.25


def test_one_dtype_and_one_numba_type_for_every_configuration():
    """Whatever the settings (each case above, and all changed at once), the record has the same dtype and numba
    types it alike: the tick is compiled once."""
    configs = [FuserConfig()] + [_config(g, n, v) for g, n, v in CASES]
    every = FuserConfig()
    for group, name, value in CASES:  # the first valid value of each setting, all together (where the rules allow)
        try:
            every = every.replace(**({group: {name: value}} if group else {name: value}))
        except ValueError:
            continue
    configs.append(every)
    records = [params_record(c) for c in configs]
    assert all(r.dtype == PARAMS_DTYPE for r in records)
    types_ = {numba.typeof(r) for r in records}
    assert len(types_) == 1, types_
    assert sum(not _same(a, b) for a, b in zip(_leaves(records[-1][0]).values(), _leaves(records[0][0]).values())) > 60
