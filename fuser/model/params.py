"""The model's parameters as one numpy record, for the compiled tick.

:class:`fuser.config.FuserConfig` stays the parameters' definition (groups,
units, defaults, validation); this module lays the groups the model reads out
as a nested structured dtype (after PX4 EKF2's grouped ``struct parameters``)
so that the compiled tick (:mod:`fuser.model.fusion`) reads
``params.gyro.noise_rad_s_rt_hz`` at a fixed offset. The record is built once
per model (:func:`params_record`); its dtype is the same for every
configuration, so numba compiles the tick once.

The layout follows the settings' type hints: a float is ``f8``, an int ``i8``,
a bool ``?``, a tuple of three floats ``(f8, 3)``; a ``Literal`` is the index
of its value among the literal's choices (:func:`choice`); an optional value
is its field plus ``has_<name>`` (the value is NaN, or zeros, when absent).
Strings and the outputs' groups are not the model's and are left out.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Literal

import numpy as np

from fuser.config import (AccelSettings, AttitudeSettings, BiasSettings, ExtrapolationSettings, FuserConfig, GnssSettings,
                          GyroSettings, ImuCheckSettings, MagSettings, ModelErrorSettings, RestSettings, UpdateSettings)

__all__ = ["MODE_ALWAYS", "MODE_AUTO", "MODE_OFF", "PARAMS_DTYPE", "choice", "params_record", "settings_dtype"]

_GROUPS: dict[str, type] = {
    "gyro": GyroSettings,
    "imu_check": ImuCheckSettings,
    "bias": BiasSettings,
    "rest": RestSettings,
    "accel": AccelSettings,
    "mag": MagSettings,
    "attitude": AttitudeSettings,
    "updates": UpdateSettings,
    "model_error": ModelErrorSettings,
    "extrapolation": ExtrapolationSettings,
    "gnss": GnssSettings,
}
"""The groups of :class:`FuserConfig` the model reads, by their field name."""


def _unwrapped(hint: Any) -> tuple[Any, bool]:
    """The hint without ``Annotated`` and ``None``: (type, optional)."""
    if typing.get_origin(hint) is typing.Annotated:
        hint = typing.get_args(hint)[0]
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        inner, _ = _unwrapped(args[0])
        return inner, True
    return hint, False


def _field_dtype(name: str, hint: Any) -> list[tuple]:
    kind, optional = _unwrapped(hint)
    origin = typing.get_origin(kind)
    if kind is float:
        fields = [(name, "f8")]
    elif kind is bool:
        fields = [(name, "?")]
    elif kind is int or origin is Literal:
        fields = [(name, "i8")]
    elif origin is tuple and all(a is float for a in typing.get_args(kind)):
        fields = [(name, "f8", (len(typing.get_args(kind)),))]
    else:
        return []  # a string or a sequence of strings: not the model's
    return fields + ([(f"has_{name}", "?")] if optional else [])


def settings_dtype(cls: type) -> np.dtype:
    """The record dtype of one settings group (module docstring)."""
    hints = typing.get_type_hints(cls, include_extras=True)
    fields: list[tuple] = []
    for f in dataclasses.fields(cls):
        fields += _field_dtype(f.name, hints[f.name])
    return np.dtype(fields, align=True)


PARAMS_DTYPE = np.dtype([(name, settings_dtype(cls)) for name, cls in _GROUPS.items()]
                        + [("rate_hz", "f8"), ("latency_ms", "f8")], align=True)
"""The parameters record: one nested record per group, then the general settings the model reads."""


def choice(cls: type, name: str, value: str) -> int:
    """The code of a ``Literal`` setting's value: its index among the literal's choices."""
    kind, _ = _unwrapped(typing.get_type_hints(cls, include_extras=True)[name])
    return typing.get_args(kind).index(value)


MODE_AUTO = choice(AttitudeSettings, "mode", "auto")
MODE_ALWAYS = choice(AttitudeSettings, "mode", "always")
MODE_OFF = choice(AttitudeSettings, "mode", "off")


def _fill(record: np.void, settings: Any) -> None:
    hints = typing.get_type_hints(type(settings), include_extras=True)
    names = record.dtype.names
    for f in dataclasses.fields(settings):
        if f.name not in names:
            continue
        value = getattr(settings, f.name)
        kind, optional = _unwrapped(hints[f.name])
        if optional:
            record[f"has_{f.name}"] = value is not None
            if value is None:
                record[f.name] = math.nan
                continue
        record[f.name] = choice(type(settings), f.name, value) if typing.get_origin(kind) is Literal else value


def params_record(config: FuserConfig) -> np.ndarray:
    """The model's parameters from ``config``: a record array of length one (index 0 is the record)."""
    out = np.zeros(1, PARAMS_DTYPE)
    for name in _GROUPS:
        _fill(out[0][name], getattr(config, name))
    out[0]["rate_hz"] = config.rate_hz
    out[0]["latency_ms"] = config.latency_ms
    return out
