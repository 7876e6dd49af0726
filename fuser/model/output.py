"""The output predictor: an estimate at every sample of the reference IMU, between the ticks.

The filter runs at the loop's rate (100 Hz by default); a real-time consumer
that reads the latest estimate at the IMU's rate otherwise holds each one for
a whole tick period (and the wait for samples in flight), and at BROAD's 600
deg/s the attitude turns by degrees meanwhile: with ``extrapolation.to =
"hold_midpoint"`` the held estimate's error is ``w T / sqrt(12)`` RMS over
the hold (issue 15: inclination 1.27 times VQF's held against 1.03 at the
tick times). PX4 EKF2 separates the two rates the same way: its filter fuses
on a delayed horizon at about 100 Hz while an output predictor integrates
every IMU sample from the filter's latest state and publishes at the IMU's
rate (EKF2 ``calculateOutputStates``).

Here, with ``extrapolation.every_imu_sample``, the tick's published
distribution with its lead taken back (the state at the tick, widened by the
model error; :mod:`fuser.model.extrapolation`) is turned by the bias-corrected
gyro through every sample of the reference IMU after the tick (of every IMU
in a slow stream, below), by the same
trapezoidal rule as the tick's integration (what the tick's hold applied
after its last sample taken back, :mod:`fuser.model.propagation`), then
carried at the newest sample's rate to the instant it is published: its
arrival, the sample describing the motion ``extrapolation.imu_delay_ms``
before it. A right rotation of a Bingham is exact (progressive paper, eq. 6):
the concentrations stay the tick's, whose variance already counts the rate
held from the tick's last sample to its lead (:mod:`fuser.model.extrapolation`).

**A slow gyro stream's hold.** In a stream slower than
``gyro.smooth_interval_s`` (a ground station's telemetry at 3 Hz) the held
rate can be a whole interval old and more: over a radio the loop waits
100-250 ms for samples in flight, and the estimate published when the tick
runs is carried over that wait. There the hold's error beyond what the tick
counted, the rate walk's ``s^2 (h^3 - c^3) / 3`` (``h`` the hold at the stamp,
``c`` the hold the tick counted; :func:`fuser.model.propagation.rate_walk2`, the
walk the samples showed) and the gap rate's after ``gyro.max_interval_s``, is
added to every axis (:func:`fuser.model_error.with_model_error`'s closed
form, no eigendecomposition); ``h`` restarts at each sample the predictor
integrates. A ground station's log at ArduPilot's default rates through flips
(``tests/test_fuser_low_rate_honesty.py``): 28-77 deg off while reporting 5-15
before, the truth in the 90 % region on 59 % of the manoeuvres' estimates;
90 % after. There the vehicle's other IMUs' samples turn the prediction too
(:mod:`fuser.loop`; the tick merges them into one stream, and between the
reference's samples they are the only rate): 43.9 -> 35.8 deg RMS in those
flips. In a faster stream the hold is within a sample interval and the
walk over it (``s^2 h^3 / 3``, 1e-7 rad^2 at 15 ms) is left out, so its
estimates keep the tick's concentrations to the bit. A gap longer than
``gyro.max_interval_s`` or a saturated sample ends the prediction until the
next tick, as does a tick without a gyro track, or one while the IMU check
keeps an IMU out (:mod:`fuser.model.imu_check`: between ticks it is not known
which IMU is wrong). The filter's state is never
touched: the next tick starts from its own posterior, not from a prediction.

Compiled with numba: it runs once per IMU sample, between the ticks, called
from Python (:mod:`fuser.loop`). The predictor is an array of one
:data:`OUTPUT` record, changed in place (``active`` False while it waits for
the next tick); an array, not the record, because numba types an array
argument in a microsecond and a record in about ten.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from core import saddlepoint
from core.bingham import Bingham
from core.bingham_kernels import rms_angle_deg, rotated_right
from core.quaternion_kernels import IDENTITY, conjugate, from_array, turned_by
from fuser.model import vec3
from fuser.model.propagation import rate_walk2, saturated
from fuser.model_error import with_model_error

__all__ = ["OUTPUT", "OutputPredictor", "advanced", "at", "started"]

OUTPUT = np.dtype([
    ("base_M", "f8", (4, 4)),  # the tick's published distribution at the tick (its lead taken back)
    ("base_Z", "f8", (4,)),
    ("turned_wxyz", "f8", (4,)),  # body rotation from the tick to the last sample integrated (bias removed)
    ("last_ns", "i8"),  # the last gyro sample integrated (loop timeline)
    ("last_rate_rad_s", "f8", (3,)),  # its raw rate
    ("covered_ns", "i8"),  # the rotation covers up to here: the tick's time until a sample after it closes the first interval
    ("held_rad", "f8", (3,)),  # raw rotation the tick's hold applied after last_ns: taken back by the first interval
    ("bias_rad_s", "f8", (3,)),
    ("active", "?"),  # False: no prediction until the next tick (no usable rate, a gap or a saturated sample)
    ("slow", "?"),  # a gyro stream slower than gyro.smooth_interval_s: a hold's error beyond the tick's is counted
    ("walk2_rad2_s3", "f8"),  # the held rate's walk^2 at the tick (fuser.model.propagation.rate_walk2)
    ("counted_s", "f8"),  # the hold after last_ns the base distribution already counts
], align=True)
"""The predictor between two ticks."""


@njit(cache=True, nogil=True)
def _store4(out: np.ndarray, q: tuple) -> None:
    for i in range(4):
        out[i] = q[i]


@njit(cache=True, nogil=True, inline="always")  # inlined: copies a record's field into an array and back
def _store44(out: np.ndarray, M: np.ndarray) -> None:
    for i in range(4):
        for j in range(4):
            out[i, j] = M[i, j]


@njit(cache=True, nogil=True)
def _as_array(q: tuple) -> np.ndarray:
    u = np.empty(4)
    for i in range(4):
        u[i] = q[i]
    return u


@njit(cache=True, nogil=True)
def started(params: np.record, out: np.ndarray, published_M: np.ndarray, published_Z: np.ndarray, has_lead: bool,
            lead_rotation: np.ndarray, counted_until_ns: int, gyro: np.record, bias_rad_s: np.ndarray) -> None:
    """``out[0]`` (:data:`OUTPUT`) the predictor after a tick: its published distribution, the body rotation its lead
    applied (``lead_rotation``, read only if ``has_lead``), the instant up to which its variance counts the held
    rate's error, the gyro (:data:`fuser.model.state.GYRO`) and bias after it; ``params`` the ``gyro`` group. Not
    ``active`` without a usable rate (no gyro yet, or the last sample saturated)."""
    o = out[0]
    track = gyro.track
    if not gyro.has_track or track.saturated:
        o.active = False
        return
    o.slow = track.has_interval_s and track.interval_s > params.smooth_interval_s
    o.walk2_rad2_s3 = rate_walk2(params, track, counted_until_ns)
    o.counted_s = max(0, counted_until_ns - track.last_ns) * 1e-9
    M = np.empty((4, 4))  # a heap array: the kernels below are compiled for those, not for the record's field
    _store44(M, published_M)
    if has_lead:
        M = rotated_right(_as_array(conjugate(from_array(lead_rotation))), M)
    _store44(o.base_M, M)
    for i in range(4):
        o.base_Z[i] = published_Z[i]
    _store4(o.turned_wxyz, IDENTITY)
    o.last_ns, o.covered_ns = track.last_ns, track.covered_ns
    vec3.store(o.last_rate_rad_s, vec3.load(track.last_rate_rad_s))
    vec3.store(o.held_rad, vec3.load(track.held_rad))
    vec3.store(o.bias_rad_s, (bias_rad_s[0], bias_rad_s[1], bias_rad_s[2]))
    o.active = True


@njit(cache=True, nogil=True)
def advanced(params: np.record, out: np.ndarray, rate_rad_s: tuple, placed_ns: int) -> bool:
    """``out[0]`` turned through one more sample of the reference IMU (``placed_ns`` on the loop's timeline;
    ``params`` the ``gyro`` group); no longer ``active`` after a gap or a saturated sample (the prediction waits for
    the next tick); unchanged for a sample not after the rotation's end (out of order). True if the prediction is
    active and now ends at ``placed_ns``."""
    o = out[0]
    if not o.active:
        return False
    if placed_ns <= o.covered_ns:
        return o.last_ns == placed_ns
    h_ns = placed_ns - o.last_ns
    if h_ns > round(params.max_interval_s * 1e9) or saturated(params, rate_rad_s):
        o.active = False
        return False
    half, covered = 0.5 * h_ns * 1e-9, (placed_ns - o.covered_ns) * 1e-9
    p, held, b = o.last_rate_rad_s, o.held_rad, o.bias_rad_s
    x = half * (rate_rad_s[0] + p[0]) - held[0] - b[0] * covered
    y = half * (rate_rad_s[1] + p[1]) - held[1] - b[1] * covered
    z = half * (rate_rad_s[2] + p[2]) - held[2] - b[2] * covered
    t = o.turned_wxyz
    _store4(t, turned_by((t[0], t[1], t[2], t[3]), x, y, z))
    o.last_ns = o.covered_ns = placed_ns
    vec3.store(o.last_rate_rad_s, rate_rad_s)
    vec3.store(o.held_rad, vec3.ZERO)
    o.counted_s = 0.0  # a new hold from this sample (the base's counted one covered an interval now integrated)
    return True


@njit(cache=True, nogil=True)
def _hold_variance_rad2(params: np.record, o: np.record, hold_s: float) -> float:
    """The per-axis variance of the last rate held ``hold_s`` after its sample: the rate walk's ``s^2 h^3 / 3`` to
    the hold's end (``max_interval_s``), then the gap rate's (:func:`fuser.model.extrapolation.lead`'s account)."""
    held_s = min(hold_s, params.max_interval_s)
    gap = params.gap_rate_rad_s * (hold_s - held_s)
    return o.walk2_rad2_s3 * held_s * held_s * held_s / 3.0 + gap * gap


@njit(cache=True, nogil=True)
def at(params: np.record, out: np.ndarray, stamp_ns: int, imu_delay_ns: int, M_out: np.ndarray, Z_out: np.ndarray) -> float:
    """The predicted distribution at ``stamp_ns`` (``out[0]`` active) into ``M_out``, ``Z_out``: the last sample's
    rate (bias removed) held from the instant it describes, ``imu_delay_ns`` before it, to the stamp; in a slow stream
    widened by the held rate's error beyond what the tick counted (module docstring). ``params`` the ``gyro`` group.
    Returns the widened distribution's RMS angle (degrees), or -1 if it has the tick's concentrations (and spread)."""
    o = out[0]
    carry_s = max(0, stamp_ns - o.covered_ns + imu_delay_ns) * 1e-9
    r, b, t = o.last_rate_rad_s, o.bias_rad_s, o.turned_wxyz
    turned = turned_by((t[0], t[1], t[2], t[3]), (r[0] - b[0]) * carry_s, (r[1] - b[1]) * carry_s, (r[2] - b[2]) * carry_s)
    base = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            base[i, j] = o.base_M[i, j]
    M = rotated_right(_as_array(turned), base)
    Z = np.empty(4)
    for i in range(4):
        Z[i] = o.base_Z[i]
    hold_s = max(0, stamp_ns - o.last_ns + imu_delay_ns) * 1e-9
    spread_deg = -1.0
    if o.slow and hold_s > o.counted_s:
        extra = _hold_variance_rad2(params, o, hold_s) - _hold_variance_rad2(params, o, o.counted_s)
        M, Z = with_model_error(M, Z, extra, extra)
        spread_deg = rms_angle_deg(saddlepoint.moments(Z))
    for i in range(4):
        Z_out[i] = Z[i]
        for j in range(4):
            M_out[i, j] = M[i, j]
    return spread_deg


@njit(cache=True, nogil=True)
def _start(params: np.ndarray, out: np.ndarray, tick_output: np.ndarray, state: np.ndarray) -> None:
    """:func:`started` from the last tick's output (:data:`fuser.model.tick.TICK_OUTPUT`) and state record; not
    ``active`` after a tick that kept an IMU out (which IMU is wrong is not known between ticks, so the state is not
    turned by the reference IMU's gyro)."""
    o, s = tick_output[0], state[0]
    if o.imu_fault:
        out[0].active = False
        return
    started(params[0].gyro, out, o.published_M, o.published_Z, o.has_lead_rotation, o.lead_rotation, o.counted_until_ns, s.gyro,
            s.bias.estimate_rad_s)


@njit(cache=True, nogil=True)
def _at(params: np.ndarray, out: np.ndarray, stamp_ns: int, imu_delay_ns: int, M_out: np.ndarray, Z_out: np.ndarray) -> float:
    """:func:`at` with the model's parameters record array."""
    return at(params[0].gyro, out, stamp_ns, imu_delay_ns, M_out, Z_out)


@njit(cache=True, nogil=True)
def _advance(params: np.ndarray, out: np.ndarray, rate_rad_s: tuple, placed_ns: int) -> bool:
    """:func:`advanced` with the model's parameters record array (an array: numba types it in a microsecond)."""
    return advanced(params[0].gyro, out, rate_rad_s, placed_ns)


@njit(cache=True, nogil=True)
def _advance_all(params: np.ndarray, out: np.ndarray, rates_rad_s: np.ndarray, placed_ns: np.ndarray) -> None:
    """:func:`advanced` through each sample in turn (row ``i`` of ``rates_rad_s`` placed at ``placed_ns[i]``), until
    the prediction stops."""
    for i in range(placed_ns.shape[0]):
        if not out[0].active:
            return
        advanced(params[0].gyro, out, (rates_rad_s[i, 0], rates_rad_s[i, 1], rates_rad_s[i, 2]), placed_ns[i])


class OutputPredictor:
    """The predictor as the loop drives it: started by the model after each tick
    (:meth:`fuser.model.FusionModel.start_output`), turned through each sample of the reference IMU
    (:meth:`advance`), read at any instant (:meth:`at`)."""

    def __init__(self, params: np.ndarray, imu_delay_ns: int) -> None:
        self._params = params
        self._imu_delay_ns = imu_delay_ns
        self._out = np.zeros(1, OUTPUT)
        self._M = np.empty((4, 4))
        self._Z = np.empty(4)

    @property
    def slow(self) -> bool:
        """The gyro stream it was started from is slower than ``gyro.smooth_interval_s`` (module docstring)."""
        return bool(self._out[0]["slow"])

    @property
    def active(self) -> bool:
        """False: nothing to predict until the next tick (no usable rate, a gap, a saturated sample, an IMU kept out)."""
        return bool(self._out[0]["active"])

    def start(self, tick_output: np.ndarray, state: np.ndarray) -> None:
        """Start from a tick's output and the state after it (:func:`started`)."""
        _start(self._params, self._out, tick_output, state)

    def stop(self) -> None:
        """No prediction until the next tick."""
        self._out[0]["active"] = False

    def advance(self, rate_rad_s: tuple[float, float, float], placed_ns: int) -> bool:
        """Turn through one more sample of the reference IMU (:func:`advanced`); True if the prediction now ends there."""
        return _advance(self._params, self._out, rate_rad_s, placed_ns)

    def advance_through(self, samples: list[tuple[tuple[float, float, float], int]]) -> None:
        """:meth:`advance` through each (rate, placed) of ``samples`` in turn, in one compiled call (after a tick,
        through the samples already received)."""
        if samples:
            rates = np.array([rate for rate, _ in samples], float)
            _advance_all(self._params, self._out, rates, np.array([placed for _, placed in samples], np.int64))

    def at(self, stamp_ns: int) -> tuple[Bingham, float | None]:
        """The predicted distribution at ``stamp_ns`` and its RMS angle in degrees, None if it is the tick's
        (:func:`at`: not widened)."""
        spread_deg = _at(self._params, self._out, stamp_ns, self._imu_delay_ns, self._M, self._Z)
        return Bingham._trusted(self._M.copy(), self._Z.copy()), (None if spread_deg < 0.0 else spread_deg)
