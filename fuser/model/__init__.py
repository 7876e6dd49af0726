"""The fusion model: turns one tick's samples into Bingham filter operations.

The state starts uniform: no prior knowledge of the attitude is needed. Per
tick (:meth:`FusionModel.step`, in :mod:`fuser.model.fusion`): each IMU's gyro
is integrated and the attitude predicted in closed form; gravity, the
magnetometer's heading and an autopilot's attitude are fused as exact
Bingham likelihoods; the gyro bias, a Gaussian beside the Bingham, is
measured at rest and learnt in motion from the tilt and heading corrections (VQF: D. Laidig,
T. Seel, "VQF: Highly accurate IMU orientation estimation with bias
estimation and magnetic disturbance rejection", Information Fusion 91, 2023).

One module per job: :mod:`~fuser.model.imu_check` (IMUs against each other),
:mod:`~fuser.model.propagation` (gyro integration and prediction), :mod:`~fuser.model.gravity`, :mod:`~fuser.model.heading`,
:mod:`~fuser.model.attitude` (the updates), :mod:`~fuser.model.velocity` (GNSS velocity aiding of the
gravity update, its pairs' low-pass in :mod:`~fuser.model.pair_lowpass`), :mod:`~fuser.model.velocity_check` (the fixes'
check of the state), :mod:`~fuser.model.field` (the reference field from the WMM), :mod:`~fuser.model.unaided`
(what an unaided accelerometer cannot see, for the published uncertainty), :mod:`~fuser.model.gate` (their
innovation gate), :mod:`~fuser.model.rest` and :mod:`~fuser.model.bias`,
:mod:`~fuser.model.body_frame` (readings in the state's body frame),
:mod:`~fuser.model.extrapolation` (the published state carried ahead of its tick),
:mod:`~fuser.model.output` (the output predictor between the ticks),
:mod:`~fuser.model.state` (the persistent state, one record), :mod:`~fuser.model.params` (the parameters, one
record), :mod:`~fuser.model.tick` (what goes in and out of a tick and between its steps),
:mod:`~fuser.model.diagnostics` (what each update did), :mod:`~fuser.model.vec3` (3-vector arithmetic).

The tick is compiled (numba): :func:`fuser.model.fusion.tick` runs a whole tick in one call, each module's
functions compiled with it; :class:`FusionModel` is the Python around it.
"""

from __future__ import annotations

from typing import Any

__all__ = ["FilterState", "FusionModel", "TickInput", "TickResult", "UpdateDiagnostic"]

_WHERE = {"FilterState": "state", "FusionModel": "fusion", "TickInput": "tick", "TickResult": "tick", "UpdateDiagnostic": "diagnostics"}


def __getattr__(name: str) -> Any:
    """The package's names, imported when first used (PEP 562): a module of the model imports without the compiled tick."""
    if name not in _WHERE:
        raise AttributeError(f"module 'fuser.model' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"fuser.model.{_WHERE[name]}"), name)
