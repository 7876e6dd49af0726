"""Scoring against a reference that arrives out of order, with repeated times or unusable rows: no crash, same errors."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from drivers.scenarios import scenario
from drivers.sim import mavlink_stream
from fuser.cli import main
from fuser.evaluate import attitude_errors


def yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Rotation about world down (NED z) by ``yaw``: (cos y/2, 0, 0, sin y/2)."""
    return np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)], axis=-1)


def test_reference_in_receive_order_with_repeats_and_bad_rows() -> None:
    rate = 0.5  # rad/s about down
    ref_t = np.arange(0, 2_000_000_000, 20_000_000, dtype=np.int64)
    ref_q = yaw_quat(rate * ref_t / 1e9)
    est_t = np.arange(100_000_000, 1_900_000_000, 10_000_000, dtype=np.int64)
    offset_deg = 2.0  # every estimate 2 degrees of yaw ahead of the reference
    est_q = yaw_quat(rate * est_t / 1e9 + np.radians(offset_deg))
    unc = np.full(est_t.size, 3.0)

    rng = np.random.default_rng(0)
    order = rng.permutation(ref_t.size)  # receive order, not time order
    t_mixed = np.concatenate([ref_t[order], ref_t[:5], [ref_t[7]]])  # repeated times
    q_mixed = np.concatenate([ref_q[order], ref_q[:5], [[np.nan, 0.0, 0.0, 0.0]]])  # a repeat that is not even finite
    t_mixed = np.concatenate([t_mixed, [ref_t[8] + 1]])
    q_mixed = np.concatenate([q_mixed, [[0.0, 0.0, 0.0, 0.0]]])  # a zero quaternion
    err = attitude_errors(est_t, est_q, unc, t_mixed, q_mixed)
    assert err.t_ns.tolist() == est_t.tolist()
    np.testing.assert_allclose(err.heading_deg, offset_deg, atol=1e-6)
    np.testing.assert_allclose(err.total_deg, offset_deg, atol=1e-6)
    np.testing.assert_allclose(err.tilt_deg, 0.0, atol=1e-6)


def test_fewer_than_two_usable_reference_times_scores_nothing() -> None:
    err = attitude_errors(np.array([1, 2, 3]), yaw_quat(np.zeros(3)), np.ones(3), np.array([5, 5]), yaw_quat(np.zeros(2)))
    assert err.t_ns.size == 0 and err.total_deg.size == 0


def test_replay_of_a_tlog_with_garbage_scores_without_crashing(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The issue's case: garbage between the packets of a .tlog, then scoring against the autopilot's attitude."""
    rng = np.random.default_rng(1)
    tlog = tmp_path / "garbage.tlog"
    with open(tlog, "wb") as f:
        for t_ns, _, data in mavlink_stream(scenario("hover", seed=3)):
            while data:  # one record per MAVLink 2 packet: 10 header bytes, payload, 2 CRC bytes
                size = 12 + data[1]
                f.write(struct.pack(">Q", (t_ns + 1_000_000) // 1000) + data[:size])
                data = data[size:]
            if rng.random() < 0.3:
                f.write(rng.integers(0, 256, int(rng.integers(1, 300)), dtype=np.uint8).tobytes())
    assert main(["replay", str(tlog), "-o", str(tmp_path / "out.mcap")]) == 0
    out = capsys.readouterr().out
    assert "error against autopilot attitude" in out or "no estimate within" in out
