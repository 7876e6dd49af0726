"""Building the compiled model's records in tests: the parameters, a part of the state with given fields.

The model's state is one numpy record (:mod:`fuser.model.state`) whose optional values carry a ``has_<name>``
flag; :func:`part` sets fields by name as the old dataclasses' constructors did (``None`` clears the flag, a value
sets it), on a fresh state's part, so that a test states only what it is about.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from drivers.samples import GnssSample
from fuser.config import FuserConfig
from fuser.model.diagnostics import DIAGNOSTIC, Diagnostic, UpdateDiagnostic, decoded, emit
from fuser.model.params import params_record
from fuser.model.state import FilterState, initial_state
from fuser.model.tick import GNSS_INPUT

__all__ = ["field_bytes", "gnss_input", "params", "part", "set_fields", "update_diagnostic"]


def params(config: FuserConfig | None = None) -> np.record:
    """The parameters record of ``config`` (default settings if None), its groups as attributes (``params().accel``)."""
    return params_record(config or FuserConfig()).view(np.recarray)[0]


def _flag(name: str, names: tuple[str, ...]) -> str | None:
    """The ``has_`` flag of field ``name``: its own, or the one it shares (``has_accel_lp`` for ``accel_lp_m_s2``, the
    low-passes' ``has_lp``, ``has_recent``); None for a field that is always present."""
    stem = name.removesuffix("_m_s2").removesuffix("_rad_s2").removesuffix("_rad_s")
    candidates = [f"has_{name}", f"has_{stem}"] + (["has_lp"] if "_lp" in name else []) + (["has_recent"] if name.startswith("recent") else [])
    return next((c for c in candidates if c in names), None)


def set_fields(record: np.record, **fields: Any) -> np.record:
    """Set ``fields`` on ``record`` in place (None clears an optional field's ``has_<name>`` flag and zeroes it, a
    value sets it); returns ``record``."""
    names = record.dtype.names
    for name, value in fields.items():
        if name not in names:
            raise KeyError(f"{name} is not a field of {names}")
        flag = _flag(name, names)
        if value is None:
            if flag is None:
                raise KeyError(f"{name} of {names} is not optional")
            record[flag] = False
            record[name] = 0
            continue
        if flag is not None:
            record[flag] = True
        record[name] = value
    return record


def part(name: str, config: FuserConfig | None = None, state: FilterState | None = None, **fields: Any) -> np.record:
    """The part ``name`` (``"gravity"``, ``"bias"``, ...) of ``state`` (a fresh one of ``config`` if None), with ``fields`` set."""
    state = state or initial_state(config or FuserConfig())
    return set_fields(getattr(state, name), **fields)


def gyro_part(**track: Any) -> np.record:
    """The state's gyro part (:data:`fuser.model.state.GYRO`) with a track of the fields ``track`` (none if empty: no
    gyro sample yet)."""
    gyro = part("gyro")
    if track:
        set_fields(gyro.track, **track)
        gyro.has_track = True
    return gyro


def update_diagnostic(diagnostic: Diagnostic) -> UpdateDiagnostic | None:
    """The :class:`~fuser.model.diagnostics.UpdateDiagnostic` (degrees, names) of a compiled update's
    :class:`~fuser.model.diagnostics.Diagnostic` (radians, codes), as the model reports it: written into a record as the
    tick does (``emit``) and decoded; None for one not ``present`` (no reading)."""
    records = np.zeros(1, DIAGNOSTIC)
    if emit(records, 0, diagnostic) == 0:
        return None
    return decoded(records)[0]


def gnss_input(fixes: Sequence[tuple[GnssSample, int, int]]) -> np.ndarray:
    """The tick's GNSS fixes as the compiled tick reads them (:data:`~fuser.model.tick.GNSS_INPUT`), laid out as
    :meth:`FusionModel.step <fuser.model.FusionModel.step>` does: each ``(sample, placed ns, stream slot)``."""
    rows = [(placed_ns, x.fix_type, x.vel_ned_m_s is not None, x.vel_ned_m_s or (0.0, 0.0, 0.0), x.vertical_velocity,
             x.speed_accuracy_m_s is not None, math.nan if x.speed_accuracy_m_s is None else x.speed_accuracy_m_s, x.filtered, slot)
            for x, placed_ns, slot in fixes]
    return np.array(rows, GNSS_INPUT)


def field_bytes(value: np.ndarray | np.void) -> dict[str, bytes]:
    """Each leaf field of a structured value (a record array, a record or one of its parts) as its bytes, by dotted
    name (``"gravity.converged"``): two values compared byte for byte without their padding, which numpy's copies do
    not copy (a copied record's padding bytes are arbitrary, so ``record.tobytes()`` of two equal states may differ)."""
    out: dict[str, bytes] = {}
    for name in value.dtype.names:
        field = value[name]
        if field.dtype.names:
            out |= {f"{name}.{leaf}": data for leaf, data in field_bytes(field).items()}
        else:
            out[name] = np.asarray(field).tobytes()
    return out
