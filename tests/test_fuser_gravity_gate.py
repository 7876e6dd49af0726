"""The converged gravity update's innovation gate, against hand-computed gates, at two loop rates.

Once converged the reading's sigma is the one that gives the correction its time constant,
``sqrt(Q T / dt) tau / T`` (fuser/model/gravity.py), which grows as ``1 / sqrt(T)``: with ``Q`` = 1e-6 rad^2 per
10-ms tick and ``tau`` = 3 s it is 17.2 deg per reading at a 100 Hz loop and 24.3 at 200 Hz, so a gate of 3 of
those would pass a 30-deg false vertical. The gate is against the low-passed down's own error instead,
``accel.lowpass_error_deg`` (0.5), with the state's doubt (here 1 deg): ``3 hypot(0.5, 1)`` = 3.35 deg at any rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import quaternion as quat
from fuser.config import AccelSettings
from fuser.model.gravity import update_gravity
from fuser.model.tick import TickContext
from model_records import params, part, update_diagnostic

G = AccelSettings().gravity_m_s2
GATE_DEG = 3.0 * math.hypot(0.5, 1.0)
P = params()
NO_GNSS = (False, (0.0, 0.0, 0.0), 0.0)


def _tilted_reading(tilt_deg: float) -> tuple[np.record, np.ndarray]:
    """A converged state whose low-pass already holds a specific force ``tilt_deg`` off the level prediction."""
    a = math.radians(tilt_deg)
    f = np.array([0.0, G * math.sin(a), -G * math.cos(a)])  # -f is down tilted by a about the body x axis
    return part("gravity", accel_lp_m_s2=f.copy(), converged=True, tilt_known=True), f


@pytest.mark.parametrize("dt_s", [0.01, 0.005])
@pytest.mark.parametrize("tilt_deg, outcome", [(GATE_DEG - 0.1, "fused"), (GATE_DEG + 0.1, "gated"), (30.0, "gated")])
def test_the_gate_is_the_low_passed_downs_error_at_any_loop_rate(dt_s, tilt_deg, outcome):
    tick = TickContext(dt_s=dt_s, process_variance_rad2=1e-6 * dt_s / 0.01, prior_doubt_deg=1.0, prior_tilt_doubt_deg=1.0)
    state, f = _tilted_reading(tilt_deg)
    reading = update_gravity(P.accel, P.updates, state, tick, tuple(f), 3.0, tuple(quat.IDENTITY), dt_s, True, *NO_GNSS)
    d = update_diagnostic(reading.diagnostic)
    assert d.innovation_deg == pytest.approx(tilt_deg, abs=1e-9)
    assert d.outcome == outcome
    # the sigma that sets the gain is kept, and is what the old gate would have used (17.2 / 24.3 deg)
    assert d.sigma_deg == pytest.approx(math.degrees(math.sqrt(1e-6 * dt_s / 0.01) * 3.0 / dt_s), rel=1e-12)
    assert d.test_ratio == pytest.approx((tilt_deg / GATE_DEG) ** 2, rel=1e-9)
