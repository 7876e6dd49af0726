"""Any stream the drivers can hand over is fused without an exception, and every estimate is a valid Bingham.

The drivers (drivers/validation.py) pass any finite vector within the sensors' full scales (gyro 35 rad/s,
accelerometer 160 m/s^2, magnetometer 10 gauss, GNSS velocity 300 m/s), any unit quaternion, any fix type, and
times as the sender stamps them: repeated, jittered, jumping ahead, going back. The compiled tick divides by
norms, intervals and variances (a float division by zero raises in numba, where numpy would give inf), so this
property test feeds the loop such streams: a zero specific force (free fall), a zero field, two samples at the same
instant, a gyro at full scale, a fix without velocity, a GNSS stream that appears late, two IMUs. Every estimate
must then have a finite, orthonormal M, concentrations <= 0 and a finite uncertainty; the quality bar's "no NaN,
overflow or exception for any valid input".

The examples come from the suite's hypothesis profile (tests/conftest.py): 100 fixed ones in every run, or a
fresh random search with ``--hypothesis-profile search``.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.samples import AttitudeSample, GnssSample, ImuSample, MagSample, SourceId
from drivers.validation import ACCEL_MAX_M_S2, GNSS_VELOCITY_MAX_M_S, GYRO_MAX_RAD_S, MAG_MAX_GAUSS
from fuser.config import FuserConfig
from fuser.loop import FusionLoop

IMU_A, IMU_B = SourceId("mavlink", 1, 1, 0), SourceId("mavlink", 1, 1, 1)
GNSS, ATTITUDE = SourceId("mavlink", 1, 1, 0), SourceId("mavlink", 1, 1, 0)
START_NS = 10_000_000_000


def _component(limit: float) -> st.SearchStrategy[float]:
    """A reading within +-limit, the edges and zero made likely."""
    return st.one_of(st.sampled_from([0.0, limit, -limit, 1e-12]), st.floats(-limit, limit, allow_nan=False))


def _vector(limit: float) -> st.SearchStrategy[tuple[float, float, float]]:
    return st.tuples(_component(limit), _component(limit), _component(limit))


PLAUSIBLE_ACCEL = st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-12.0, -7.0))
PLAUSIBLE_MAG = st.tuples(st.floats(0.1, 0.3), st.floats(-0.1, 0.1), st.floats(0.3, 0.5))

STEP_NS = st.one_of(
    st.sampled_from([0, 1, 2_500_000, 5_000_000]),  # repeated, 1 ns apart, 400 and 200 Hz
    st.integers(1, 20_000_000),  # jitter
    st.integers(20_000_000, 3_000_000_000),  # gaps up to 3 s
    st.integers(-50_000_000, -1),  # the sender's clock going back
)


@st.composite
def _sample(draw, t_ns: int):
    kind = draw(st.sampled_from(["imu", "imu", "imu", "imu_b", "mag", "attitude", "gnss"]))
    if kind in ("imu", "imu_b"):
        accel = draw(st.one_of(_vector(ACCEL_MAX_M_S2), PLAUSIBLE_ACCEL))
        mag = draw(st.one_of(st.none(), _vector(MAG_MAX_GAUSS), PLAUSIBLE_MAG))
        gyro = draw(st.one_of(_vector(GYRO_MAX_RAD_S), _vector(0.5)))
        return ImuSample(t_ns, gyro, accel, mag, IMU_A if kind == "imu" else IMU_B)
    if kind == "mag":
        return MagSample(t_ns, draw(st.one_of(_vector(MAG_MAX_GAUSS), PLAUSIBLE_MAG)), IMU_A)
    if kind == "attitude":
        q = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 4)))
        norm = float(np.linalg.norm(q))
        q = tuple((q / norm).tolist()) if norm > 1e-3 else (1.0, 0.0, 0.0, 0.0)
        return AttitudeSample(t_ns, q, ATTITUDE)  # type: ignore[arg-type]
    fix = draw(st.integers(0, 6))
    velocity = draw(st.one_of(st.none(), _vector(GNSS_VELOCITY_MAX_M_S), _vector(2.0))) if fix >= 2 else None
    accuracy = draw(st.one_of(st.none(), st.sampled_from([1e-9, 0.3, 50.0]), st.floats(1e-6, 100.0)))
    position = draw(st.one_of(st.none(), st.tuples(st.floats(-90.0, 90.0), st.floats(-180.0, 180.0), st.floats(-1_000.0, 100_000.0))))
    lat, lon, alt = position if position is not None and fix >= 2 else (None, None, None)
    return GnssSample(t_ns, fix, velocity, draw(st.booleans()), accuracy, lat, lon, alt, draw(st.booleans()), GNSS)


@st.composite
def streams(draw):
    """Samples with their receive times: a stretch at rest first (so that the filter converges and the updates run)
    then anything."""
    out, t = [], START_NS
    for k in range(200):  # 1 s at 200 Hz, level, at rest
        t += 5_000_000
        out.append((ImuSample(t, (0.0, 0.0, 0.0), (0.0, 0.0, -9.80665), (0.21, 0.0, 0.43), IMU_A), t + 2_000_000))
    for _ in range(draw(st.integers(1, 150))):
        t = max(0, t + draw(STEP_NS))
        out.append((draw(_sample(t)), t + draw(st.integers(0, 30_000_000))))
    return out


def _check(estimates) -> None:
    for e in estimates:
        M, Z = np.array(e.M), np.array(e.Z)
        assert np.all(np.isfinite(M)) and np.all(np.isfinite(Z)), e
        assert np.allclose(M @ M.T, np.eye(4), atol=1e-6), e
        assert np.all(Z <= 0.0) and Z[-1] == 0.0, e
        assert math.isfinite(e.uncertainty_deg) and 0.0 <= e.uncertainty_deg <= 180.0, e
        assert all(math.isfinite(a) for a in e.q_wxyz + e.euler_deg), e


CONFIGS = {
    "default": {},
    "no GNSS aiding": {"gnss": {"enabled": False}},
    "6-D (magnetometer off)": {"mag": {"enabled": False}},
    "attitude always fused": {"attitude": {"mode": "always"}},
}


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(stream=streams(), config=st.sampled_from(sorted(CONFIGS)), rate_hz=st.sampled_from([50.0, 100.0, 400.0]))
def test_any_stream_the_drivers_pass_is_fused_into_valid_estimates(stream, config, rate_hz):
    loop = FusionLoop(FuserConfig(rate_hz=rate_hz).replace(**CONFIGS[config]))
    estimates = []
    for sample, receive_ns in sorted(stream, key=lambda s: s[1]):
        estimates += loop.advance(receive_ns)
        estimates += loop.push(sample, receive_ns)
    estimates += loop.flush()
    assert loop.counters["ticks"] >= 50  # the stretch at rest alone makes them: the property is not vacuous
    _check(estimates)
