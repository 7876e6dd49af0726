"""Prediction: the gyro integrated over the whole tick, then ``x_k = x_(k-1) (x) u (x) w`` in closed form.

**Integration over the whole tick, at any IMU rate.** Every IMU of the
vehicle samples the same body rate, so their samples, placed on the loop's
timeline, form one stream. The attitude is carried from the end of the
previous tick to the end of this one:

* between two samples the rate is their mean (trapezoidal rule: holding the
  new rate over the preceding interval would lag the attitude by half a
  sample period, a degree at 600 deg/s and 286 Hz);
* after the last sample the rate is held (the best estimate of the rate
  until the next sample), for at most ``gyro.max_interval_s``;
* when the next sample arrives the interval is integrated by the trapezoidal
  rule and what the hold already applied is taken back, so an interval
  spanning several ticks is spread over them and the turn is complete.

**Process noise** (per-axis angle variance; :func:`predict`): the gyro's
white noise, the residual bias as a correlated error, the scale error at
the tick's rate; the rate's own uncertainty between samples from a random
walk of the rate with intensity ``gyro.rate_walk_rad_s_rt_s`` (``s_a``):
interpolating an interval ``h`` between two samples leaves an error of
variance ``s_a^2 h^3 / 12`` (the integral of a Brownian bridge), holding the
rate for ``h`` one of ``s_a^2 h^3 / 3``. The first enters the state when an
interval is closed; the second only the published estimate while the hold
lasts (:attr:`Motion.hold_variance_rad2`), since the next sample corrects
what the hold applied, unless the hold runs out (then it enters the state,
and the rest of the gap counts at ``gyro.gap_rate_rad_s``).

**The rate walk the samples show.** ``s_a`` is the configured floor: what
the samples themselves show may be rougher, and at a ground station's
telemetry rates (ArduPilot's ``RAW_IMU`` at 2-4 Hz) through a manoeuvre it
is far rougher: a random walk of the rate leaves consecutive slopes
``(w_k - w_(k-1)) / h_k`` that differ by a variance of ``s^2 (1/h_k +
1/h_(k-1))``, while a rate that changes steadily (a turn's entry) leaves them
equal. So each interval's intensity is ``max(s_a^2, e^2 / (1/h_k +
1/h_(k-1)))``, ``e`` the change of slope (per axis, the three averaged as
the noise is isotropic: the trace is kept), in the interval's own variance
and, until the next interval, in the hold's (:func:`rate_walk2`, also the published lead's,
:mod:`fuser.model.extrapolation`). One change of slope is a noisy measure
(three degrees of freedom), so it is peak-held: a rougher interval
replaces the held value at once, and the held value is let go once it is
older than ``gyro.rate_window_s`` (the next interval's then stands): a
manoeuvre widens the estimate from its first rough interval, keeps it wide
while it lasts, and lets it go a window after it. Only a stream whose
sample interval (low-passed over the rate window) is longer than
``gyro.smooth_interval_s`` (30 ms) counts it: sampled faster, the rate's
path between two samples is the one they show (an IMU's anti-alias filter
keeps the integral of what it smooths), and a change of slope there is the
rate the samples already follow; a dropout in a fast stream is one long
interval, not a slow stream. Counted at 286 Hz, BROAD's tapping trial took
its taps for unseen motion, trusted the tapped accelerometer more, and went
from 1.16 to 1.52 deg; BROAD and the logs in logs/ (200-400 Hz) replay to
the same bytes as without it. On a ground station's log at the
default stream rates through the simulated multirotor's aggressive
manoeuvres (``tests/test_fuser_low_rate_honesty.py``, against the
simulator's attitude): 54.5 deg off reporting 9.0 before, the truth in the
90 % region 10 % of the time there and 71 % over the flight; 43.9 reporting
39.2 with it, 59 % and 88 %.

**Saturation.** A sample at or beyond ``gyro.saturation_fraction`` of the
range on any axis says only that the rate is out of range (or the sensor
failed): from the last good sample to the next one the rate is unknown, the
attitude is not turned, and the uncertainty grows at ``gyro.range_rad_s``.

The rotation ``u`` and the noise ``w`` (isotropic) then give the prediction
in closed form (progressive paper, Alg. 1: ``M`` rotated by ``u`` on the
right, eq. 6; composition with ``w`` by moment matching, QBF paper, A.9).

The noise's moments come from a table of coefficients computed once per
model (:func:`noise_table`), after VQF's parameter / state / coefficient
split (``VQFParams``, ``VQFState``, ``VQFCoefficients`` in dlaidig/vqf): the
parameters are the settings (:mod:`fuser.model.params`), the state the record
(:mod:`fuser.model.state`), and the coefficients what follows from the
parameters alone.

Compiled with numba for the tick (:func:`fuser.model.fusion.tick`): the gyro
stream's track is the state's ``gyro`` part (:data:`fuser.model.state.GYRO`),
changed in place; :class:`~fuser.model.tick.Motion` and
:class:`~fuser.model.tick.Prediction` are what a tick hands on.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from core import saddlepoint
from core.bingham_kernels import rotated_right
from core.normalization import _CONVERGED, MIN_MOMENT
from core.quaternion_kernels import IDENTITY, from_rotvec
from fuser.model import vec3
from fuser.model.bias import correlation_s, variance_rad2_s2
from fuser.model.tick import Motion, Prediction

__all__ = ["integrate_gyro", "isotropic_noise", "noise_table", "predict", "rate_hz", "rate_walk2", "saturated"]

_NOISE_STEPS = 20
"""The process noise's variance in steps of 5%: the table's key is ``round(log(variance) * 20)``."""
_NOISE_TABLE_SIZE = 4096
"""Keys -2048 to 2047: variances from ``exp(-102)`` to ``exp(102)`` rad^2; one outside is computed each time."""
_FIT_ITERATIONS = np.int64(60)  # an np.int64: a Python int would be a literal, compiled apart from Python callers' int
"""Gauss-Newton steps of the composition's moment match at most (:func:`core.normalization.fit_dispersion_trusted`'s)."""


@njit(cache=True, nogil=True)
def saturated(params: np.record, rate: tuple) -> bool:
    """A gyro sample at or beyond ``saturation_fraction`` of the range on any axis (module docstring); ``params`` the
    ``gyro`` group (:mod:`fuser.model.params`)."""
    limit = params.saturation_fraction * params.range_rad_s
    return abs(rate[0]) >= limit or abs(rate[1]) >= limit or abs(rate[2]) >= limit


@njit(cache=True, nogil=True)
def rate_hz(track: np.record, now_ns: int) -> float:
    """The gyro stream's measured rate at ``now_ns`` (``track``: :data:`fuser.model.state.GYRO_TRACK`): a stream
    that stops is slow."""
    interval = max(track.interval_s if track.has_interval_s else 0.0, (now_ns - track.last_ns) * 1e-9)
    return 1.0 / interval if interval > 0.0 else math.inf


@njit(cache=True, nogil=True)
def _merged(params: np.record, imu: np.ndarray, after: bool, after_ns: int) -> tuple:
    """``(found, t_ns, rate, saturated)``: the tick's gyro stream at its first instant after ``after_ns`` (at its
    first instant if not ``after``), saturated or not; the samples of several IMUs at one instant averaged (the
    unsaturated ones, if any, in the tick's order; all saturated: the first). For a tick whose samples are not each
    at its own instant in order: a scan per instant, no array (a few samples a tick)."""
    found = False
    t = 0
    for i in range(imu.shape[0]):
        ti = imu[i].placed_ns
        if (not after or ti > after_ns) and (not found or ti < t):
            found, t = True, ti
    if not found:
        return False, t, vec3.ZERO, False
    count = 0
    sx = sy = sz = 0.0
    first = -1
    first_any = -1
    for i in range(imu.shape[0]):
        if imu[i].placed_ns != t:
            continue
        if first_any < 0:
            first_any = i
        r = vec3.load(imu[i].gyro_rad_s)
        if not saturated(params, r):
            if count == 0:
                first = i
            sx, sy, sz = sx + r[0], sy + r[1], sz + r[2]
            count += 1
    if count == 0:
        return True, t, vec3.load(imu[first_any].gyro_rad_s), True
    if count == 1:
        return True, t, vec3.load(imu[first].gyro_rad_s), False
    return True, t, (sx / count, sy / count, sz / count), False


@njit(cache=True, nogil=True)
def rate_walk2(params: np.record, track: np.record, now_ns: int) -> float:
    """The rate walk's intensity^2 (rad^2/s^3) for a hold after the track's last sample, at ``now_ns``: the
    configured one, or the roughness the track holds if rougher and not older than the rate window (module
    docstring); ``params`` the ``gyro`` group."""
    held = track.walk2_rad2_s3 if now_ns - track.walk2_ns <= round(params.rate_window_s * 1e9) else 0.0
    return max(params.rate_walk_rad_s_rt_s * params.rate_walk_rad_s_rt_s, held)


@njit(cache=True, nogil=True)
def _shown_walk2(slope: tuple, h_s: float, last_slope: tuple, last_h_s: float) -> float:
    """The rate walk's intensity^2 that two consecutive intervals' slopes show: the change of slope's variance per
    axis over ``1/h + 1/h_last`` (module docstring)."""
    ex, ey, ez = slope[0] - last_slope[0], slope[1] - last_slope[1], slope[2] - last_slope[2]
    return (ex * ex + ey * ey + ez * ez) / 3.0 / (1.0 / h_s + 1.0 / last_h_s)


@njit(cache=True, nogil=True)
def integrate_gyro(params: np.record, gyro: np.record, imu: np.ndarray, tick_start_ns: int, tick_end_ns: int) -> Motion:
    """The gyro stream carried from ``tick_start_ns`` to ``tick_end_ns`` (the loop's timeline) with this tick's
    samples ``imu`` (:data:`fuser.model.tick.IMU_INPUT`, each at its placed time in the tick); ``gyro``'s track
    (:data:`fuser.model.state.GYRO`) is changed to the one after it (module docstring). ``params`` the ``gyro``
    group."""
    max_ns = round(params.max_interval_s * 1e9)
    walk2 = params.rate_walk_rad_s_rt_s * params.rate_walk_rad_s_rt_s
    max_hold_s3 = params.max_interval_s * params.max_interval_s * params.max_interval_s
    x = y = z = known_ns = gap_ns = saturated_ns = 0.0
    closed = 0.0
    gaps = saturated_samples = 0
    # the track's fields as locals through the samples
    track = gyro.track
    started = gyro.has_track
    last_ns, covered_ns = track.last_ns, track.covered_ns
    last_rate = vec3.load(track.last_rate_rad_s)
    held = vec3.load(track.held_rad)
    has_interval, interval_s, last_saturated = track.has_interval_s, track.interval_s, track.saturated
    has_slope, last_slope, last_h_s = track.has_slope, vec3.load(track.slope_rad_s2), track.slope_h_s
    shown2, shown2_ns = track.walk2_rad2_s3, track.walk2_ns
    window_ns = round(params.rate_window_s * 1e9)
    n = imu.shape[0]
    in_order = True  # the common case, one IMU: every sample its own instant, in order
    for i in range(1, n):
        if imu[i].placed_ns <= imu[i - 1].placed_ns:
            in_order = False
    k = 0
    t = tick_start_ns  # an int64 from the start: a literal 0 would compile _merged a second time
    while True:
        if in_order:
            if k == n:
                break
            t = imu[k].placed_ns
            rate = vec3.load(imu[k].gyro_rad_s)
            is_saturated = saturated(params, rate)
        else:
            found, t, rate, is_saturated = _merged(params, imu, k > 0, t)
            if not found:
                break
        k += 1
        if is_saturated:
            saturated_samples += 1
        if not started:  # the first sample ever: nothing before it is known
            gap_ns += t - tick_start_ns
            started = True
            last_ns, last_rate, covered_ns, held, has_interval, interval_s, last_saturated = t, rate, t, vec3.ZERO, False, 0.0, is_saturated
            continue
        h_ns = t - last_ns
        h_s = h_ns * 1e-9
        interval = interval_s + min(1.0, h_s / params.rate_window_s) * (h_s - interval_s) if has_interval else h_s
        hold_walk2 = max(walk2, shown2)  # what the hold since the last sample was carried with
        integrated = False
        if is_saturated or last_saturated:  # no rate from the last good sample to the next: what a hold applied stays
            saturated_ns += t - covered_ns
            if not last_saturated and covered_ns < last_ns + max_ns:
                held_s = (covered_ns - last_ns) * 1e-9
                closed += hold_walk2 * (held_s * held_s * held_s) / 3.0
        elif h_ns <= max_ns:
            h = h_ns * 1e-9
            half = 0.5 * h
            x += half * (rate[0] + last_rate[0]) - held[0]
            y += half * (rate[1] + last_rate[1]) - held[1]
            z += half * (rate[2] + last_rate[2]) - held[2]
            known_ns += t - covered_ns
            slope = ((rate[0] - last_rate[0]) / h, (rate[1] - last_rate[1]) / h, (rate[2] - last_rate[2]) / h) if h > 0.0 else vec3.ZERO
            if t - shown2_ns > window_ns:  # the held roughness is older than the window: let go (module docstring)
                shown2 = 0.0
            if has_slope and interval > params.smooth_interval_s:  # a stream slower than smooth: its roughness, peak-held
                now2 = _shown_walk2(slope, h, last_slope, last_h_s)
                if now2 >= shown2:
                    shown2, shown2_ns = now2, t
            closed += max(walk2, shown2) * (h * h * h) / 12.0
            integrated, last_slope, last_h_s = h > 0.0, slope, h
        else:  # a gap: the rate is held to max_interval after the last sample (what it applied stays), then unknown
            gaps += 1
            hold_end = last_ns + max_ns
            if covered_ns < hold_end:  # the hold runs out in this tick
                dt_hold = (hold_end - covered_ns) * 1e-9
                x += last_rate[0] * dt_hold
                y += last_rate[1] * dt_hold
                z += last_rate[2] * dt_hold
                known_ns += hold_end - covered_ns
                closed += hold_walk2 * max_hold_s3 / 3.0
            gap_ns += t - max(covered_ns, hold_end)
        if not integrated:  # a gap or a saturated sample: the next slope has nothing to be compared with
            shown2 = 0.0
        has_slope = integrated
        last_ns, last_rate, covered_ns, held, has_interval, interval_s, last_saturated = t, rate, t, vec3.ZERO, True, interval, is_saturated
    held_tick = imu.shape[0] == 0
    if not started:
        return Motion(vec3.ZERO, 0.0, 0.0, (tick_end_ns - tick_start_ns) * 1e-9, 0.0, 0, 0.0, 0, False)
    gyro.has_track = True
    track.last_ns, track.covered_ns = last_ns, tick_end_ns
    vec3.store(track.last_rate_rad_s, last_rate)
    track.has_interval_s, track.interval_s, track.saturated = has_interval, interval_s, last_saturated
    track.has_slope, track.slope_h_s, track.walk2_rad2_s3, track.walk2_ns = has_slope, last_h_s, shown2, shown2_ns
    vec3.store(track.slope_rad_s2, last_slope)
    hold_walk2 = rate_walk2(params, track, tick_end_ns)
    if last_saturated:
        saturated_ns += tick_end_ns - covered_ns
        vec3.store(track.held_rad, vec3.ZERO)
        return Motion((x, y, z), known_ns * 1e-9, closed, gap_ns * 1e-9, saturated_ns * 1e-9, saturated_samples, 0.0, gaps, held_tick)
    # hold the last rate to the tick's end, for at most max_interval after the sample
    hold_end = min(tick_end_ns, last_ns + max_ns)
    start = covered_ns
    dt_hold = max(0, hold_end - start) * 1e-9
    hx, hy, hz = last_rate[0] * dt_hold, last_rate[1] * dt_hold, last_rate[2] * dt_hold
    vec3.store(track.held_rad, (held[0] + hx, held[1] + hy, held[2] + hz))
    known_ns += max(0, hold_end - start)
    gap_ns += tick_end_ns - max(hold_end, start)
    age_s = (tick_end_ns - last_ns) * 1e-9
    if tick_end_ns - last_ns >= max_ns:
        if start < last_ns + max_ns:  # the hold runs out in this tick: what it applied stays unverified
            closed += hold_walk2 * max_hold_s3 / 3.0
        hold_variance = 0.0
    else:
        hold_variance = hold_walk2 * (age_s * age_s * age_s) / 3.0
    return Motion((x + hx, y + hy, z + hz), known_ns * 1e-9, closed, gap_ns * 1e-9, saturated_ns * 1e-9, saturated_samples,
                  hold_variance, gaps, held_tick)


@njit(cache=True, nogil=True)
def isotropic_noise(variance_rad2: float) -> tuple:
    """``(M, Z)`` of the isotropic rotation noise whose per-axis angle variance is ``variance_rad2``: mode at the
    identity (last column), ``Z = [z, z, z, 0]``.

    The vector part of a small rotation is half its angle, and a Bingham's
    ``E[y_i^2] -> 1/(2|z_i|)``, so ``z = -2 / variance``.
    """
    M = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            M[i, j] = 1.0 if i == (j + 1) % 4 else 0.0  # columns x, y, z, then the mode w
    return M, _noise_concentrations(variance_rad2)


@njit(cache=True, nogil=True)
def _noise_concentrations(variance_rad2: float) -> np.ndarray:
    """``Z = [z, z, z, 0]`` of :func:`isotropic_noise`."""
    z = -2.0 / variance_rad2
    Z = np.empty(4)
    Z[0] = Z[1] = Z[2] = z
    Z[3] = 0.0
    return Z


@njit(cache=True, nogil=True)
def _noise_moment(variance_rad2: float) -> float:
    """``b``: the first moment ``E[x_1^2]`` (each of the three vector axes') of :func:`isotropic_noise`."""
    return saddlepoint.moments(_noise_concentrations(variance_rad2))[0]


def noise_table() -> np.ndarray:
    """The model's coefficients: the process noise's moment ``b`` (:func:`_noise_moment`) for each variance step
    ``exp(k / 20)``, indexed by ``k`` plus half the table's size, NaN until a tick first needs it. Ticks repeat
    their length and the bias variance settles, so few distinct values occur and each is computed once per model."""
    return np.full(_NOISE_TABLE_SIZE, np.nan)


@njit(cache=True, nogil=True)
def _process_noise_moment(variance_rad2: float, floor_rad2: float, table: np.ndarray) -> float:
    """``b`` of the process noise for a variance, in steps of 5% (``exp(k / 20)``), through the ``table``
    (:func:`noise_table`); a step beyond the table is computed each time."""
    key = round(math.log(max(variance_rad2, floor_rad2)) * _NOISE_STEPS)  # half to even, as Python's
    i = key + table.shape[0] // 2
    if i < 0 or i >= table.shape[0]:
        return _noise_moment(math.exp(key / _NOISE_STEPS))
    if math.isnan(table[i]):
        table[i] = _noise_moment(math.exp(key / _NOISE_STEPS))
    return table[i]


@njit(cache=True, nogil=True)
def predict(gyro: np.record, bias_params: np.record, attitude: np.record, bias: np.record, motion: Motion, dt_s: float,
            noise_table: np.ndarray) -> Prediction:
    """``attitude`` (:data:`fuser.model.state.ATTITUDE`) carried over the tick by the bias-corrected rotation, with
    the tick's process noise; the state is not changed. ``gyro``, ``bias_params`` the parameter groups, ``bias`` the
    state's (:data:`fuser.model.state.BIAS`), ``noise_table`` the coefficients (:func:`noise_table`).

    A residual bias error ``e`` persists: over its correlation time ``tau``
    it turns the attitude by ``e tau``, the same as white noise of variance
    ``e^2 tau dt`` per tick; ``(e dt)^2`` would understate it by ``tau/dt``
    and make the filter overconfident (and the bias loop underdamped).

    The noise ``w`` is isotropic: its inertia is ``diag(a, b, b, b)`` and the
    composed inertia ``a S + b (I - S)`` (:meth:`core.bingham.Bingham.compose`):
    the principal directions are kept, the moments contract towards uniform,
    ``omega' = (1 - 4 b) omega + b``, and ``Z`` is fitted to them from the
    rotated distribution's.
    """
    variance = gyro.noise_rad_s_rt_hz * gyro.noise_rad_s_rt_hz * dt_s + variance_rad2_s2(bias) * correlation_s(bias_params) * dt_s
    gap = gyro.gap_rate_rad_s * motion.gap_s
    unknown = gyro.range_rad_s * motion.saturated_s
    variance += motion.closed_variance_rad2 + gap * gap + unknown * unknown
    u = IDENTITY
    has_rate = motion.known_s > 0.0
    rate_norm = 0.0
    M = np.empty((4, 4))  # the state's (not written), then rotated
    for i in range(4):
        for j in range(4):
            M[i, j] = attitude.M[i, j]
    if has_rate:
        e = bias.estimate_rad_s
        rx = motion.raw_rotation_rad[0] - e[0] * motion.known_s
        ry = motion.raw_rotation_rad[1] - e[1] * motion.known_s
        rz = motion.raw_rotation_rad[2] - e[2] * motion.known_s
        angle = math.sqrt(rx * rx + ry * ry + rz * rz)
        rate_norm = angle / motion.known_s
        u = from_rotvec(rx, ry, rz)
        scale = gyro.scale_error_fraction * angle
        variance += scale * scale
        u_array = np.empty(4)
        for i in range(4):
            u_array[i] = u[i]
        M = rotated_right(u_array, M)
    # composed with the noise: the moments contracted towards uniform, Z fitted from the rotated distribution's
    b = _process_noise_moment(variance, gyro.min_process_variance_rad2, noise_table)
    start = np.empty(4)
    for i in range(4):
        start[i] = attitude.Z[i]
    moments = saddlepoint.moments(start)
    target = np.empty(4)
    for i in range(4):
        target[i] = (1.0 - 4.0 * b) * moments[i] + b
    Z, fitted = saddlepoint.fit_moments(target, start, MIN_MOMENT, _CONVERGED, _FIT_ITERATIONS)
    return Prediction(M, Z, fitted, has_rate, u, has_rate, rate_norm, variance)
