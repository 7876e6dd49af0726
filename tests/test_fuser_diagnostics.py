"""Per-update diagnostics: what each update did, recorded on /diagnostics and kept for the status.

The magnet log (logs/sim_magnet.mcap: a magnet brought near the sensor from 6 s to 9 s) is replayed; which
heading readings must be gated, and why, is computed independently from the recorded magnetometer samples
(their norm against the reference field) and the recorded truth (their dip against the true down).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from core import quaternion as quat
from core.earth_field import field_ned_gauss
from drivers.samples import GnssSample, ImuSample
from fuser.config import FuserConfig, MagSettings
from fuser.loop import FusionLoop
from fuser.record import CHANNELS, read_log
from fuser.replay import replay
from fusion_inputs import SRC, TICK, imu_at

LOG = Path(__file__).resolve().parent.parent / "logs" / "sim_magnet.mcap"


def _reference_field(log) -> np.ndarray:
    """The field the model must use: none is configured, so the WMM's at the log's first GNSS fix, on the
    undated default (the simulated flight's clock is not a Unix time)."""
    fix = next(s for s, _ in log.inputs() if isinstance(s, GnssSample) and s.lat_deg is not None)
    return np.asarray(field_ned_gauss(fix.lat_deg, fix.lon_deg, fix.alt_m, MagSettings().wmm_undated_decimal_year))


def _expected_heading_gate(log, config: FuserConfig) -> dict[int, str]:
    """Per recorded magnetometer sample (by its time): the gate the reading must meet, from the field's
    norm and its dip against the true down alone, or "" if neither is off by more than half again the gate's
    margin (readings near a threshold are left out)."""
    field = _reference_field(log)
    ref_norm, ref_dip = float(np.linalg.norm(field)), math.degrees(math.asin(field[2] / np.linalg.norm(field)))
    truth = log.truth()
    t_truth = np.array([t for t, _ in truth])
    q_truth = np.array([q for _, q in truth])
    out = {}
    for s, _ in log.inputs():
        if not isinstance(s, ImuSample) or s.mag_gauss is None:
            continue
        m = np.asarray(s.mag_gauss)
        norm_off = abs(np.linalg.norm(m) - ref_norm) / ref_norm / config.mag.norm_gate_fraction
        down = quat.rotate(quat.conjugate(q_truth[min(np.searchsorted(t_truth, s.t_ns), len(t_truth) - 1)]), [0.0, 0.0, 1.0])
        dip_off = abs(math.degrees(math.asin(float(m @ down) / np.linalg.norm(m))) - ref_dip) / config.mag.dip_gate_deg
        if norm_off > 1.5:
            out[s.t_ns] = "norm"
        elif norm_off < 0.5 and dip_off > 1.5:
            out[s.t_ns] = "dip"
        elif norm_off < 0.5 and dip_off < 0.5:
            out[s.t_ns] = ""
    return out


def test_replayed_heading_outcomes_match_the_magnet(tmp_path):
    config = FuserConfig()
    out = tmp_path / "out.mcap"
    replay(LOG, out, config, progress=None)
    fused = read_log(out)
    schema = CHANNELS["/diagnostics"]
    records = [json.loads(m.data) for m in fused.of(["/diagnostics"])]
    estimates = [e for e in fused.estimates() if not e.predicted]  # the ticks' (the output predictor's run no update)
    assert len(records) >= 0.99 * len(estimates)  # every tick here runs the heading update, but for a dropped IMU sample's
    field = next(u for r in records for u in r["updates"] if u["update"] == "mag_field" and u["reason"] == "wmm")
    assert field["field_ned_gauss"] == pytest.approx(_reference_field(read_log(LOG)).tolist(), abs=1e-12)
    for r in records[::50]:
        jsonschema.validate(r, schema)
    sensor_time = {e.t_ns: e.sensor_t_ns for e in estimates}
    expected = _expected_heading_gate(read_log(LOG), config)
    t0 = min(expected)
    checked = {"norm": 0, "dip": 0, "": 0}
    for r in records:
        heading = [u for u in r["updates"] if u["update"] == "heading"]
        # one magnetometer sample per 10-ms tick; its time lies within the tick on the sensor's clock
        mine = [t for t in expected if sensor_time[r["t_ns"]] - TICK < t <= sensor_time[r["t_ns"]]]
        if not heading or len(mine) != 1 or (mine[0] - t0) * 1e-9 < 2.0:
            continue  # before the heading has converged, or no single reading to compare with
        reason = expected[mine[0]]
        u = heading[0]
        if reason:
            assert u["outcome"] == "gated" and u["reason"] == reason, (r, reason)
        else:
            assert u["outcome"] in ("fused", "reanchored"), r
            assert u["sigma_deg"] > 0 and (u["test_ratio"] <= 1.0) == (u["outcome"] == "fused")
        checked[reason] += 1
    assert checked["norm"] > 100 and checked[""] > 500, checked  # the magnet's 3 s, and the rest of the flight
    final = estimates[-1].counters
    gated = [u for r in records for u in r["updates"] if u["update"] == "heading" and u["outcome"] == "gated"]
    assert final["mag_gated_norm"] == sum(u["reason"] == "norm" for u in gated)
    assert final.get("mag_gated_dip", 0) == sum(u["reason"] == "dip" for u in gated)


def test_gravity_diagnostics_say_why_an_impact_is_gated():
    """A sustained sideways 1.8 g: the low-passed norm leaves the gate (reason "norm"); before, the readings are
    fused with an innovation that is the tilt the acceleration fakes, within the gate."""
    loop = FusionLoop(FuserConfig(latency_ms=0.0).replace(latency={"adaptive": False}))
    q = quat.from_rotvec([0.1, 0.0, 0.0])
    outcomes = []
    for k in range(1, 401):
        t = k * TICK
        loop.push(imu_at(q, t, accel_extra=(6.0, 3.0, -8.0) if k > 300 else (0.0, 0.0, 0.0)), t)
        for e in loop.advance(t):
            outcomes.append(next(d for d in e.diagnostics if d["update"] == "gravity"))
    latest = loop.diagnostics()
    assert set(latest) == {"gravity", "heading", "mag_field"} and latest["gravity"]["t_ns"] == 400 * TICK
    assert latest["mag_field"]["reason"] == "fallback" and latest["mag_field"]["t_ns"] == TICK  # no GNSS: reported once, at the start
    settled = outcomes[200:300]
    assert all(d["outcome"] == "fused" and d["innovation_deg"] < 0.5 for d in settled)
    assert outcomes[-1]["outcome"] == "gated" and outcomes[-1]["reason"] == "norm" and outcomes[-1]["innovation_deg"] is None
    assert latest["gravity"]["reason"] == "norm"
    assert SRC == loop.reference_imu
