"""What ``report`` (and the scores ``replay`` prints) say about a fused log that cannot be scored fairly.

* A log with no IMU messages (ATTITUDE and GPS only) is fused into estimates that carry no IMU time; ``report`` said
  it "holds no estimates ... fuse it first", of a file that held thousands.
* A log with a slow IMU (a DataFlash log with one IMU at 10 Hz) is fused with the autopilot's own attitude (ATT, in
  ``auto`` mode below 20 Hz), then scored against that same ATT as the EKF3 reference: the score says how closely the
  fuser followed its input, and nothing said so.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.samples import AttitudeSample, SourceId
from fuser.codec import Estimate
from fuser.errors import UsageError
from fuser.record import McapRecorder
from fuser import batch
from fuser.report import score_log, write_report

SRC = SourceId("mavlink", 1, 1, 0)
IDENTITY = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))
N = 200
"""Ticks of 0.1 s: 20 s."""


def _estimate(k: int, counters: dict[str, int], imu_time: bool = True) -> Estimate:
    t = k * 100_000_000
    return Estimate(t, (1.0, 0.0, 0.0, 0.0), IDENTITY, (-100.0, -100.0, -100.0, 0.0), 1.0, (0.0, 0.0, 0.0),
                    counters, t if imu_time else None)


def _log(path: Path, attitude_unused: int | None, imu_time: bool = True) -> Path:
    """An imported DataFlash log (EKF3 truth from ATT) with its ATT as attitude inputs, fused: ``attitude_unused`` of
    the N ATT samples left unused (None: the counter absent, every one taken)."""
    with McapRecorder(path, metadata={"source": "ArduPilot DataFlash one10.BIN",
                                      "reference": "EKF3 (ArduPilot ATT: the autopilot's estimate, NOT ground truth)"}) as rec:
        for k in range(N):
            t = k * 100_000_000
            rec.write_truth(t, (1.0, 0.0, 0.0, 0.0))
            rec.write_sample(AttitudeSample(t, (1.0, 0.0, 0.0, 0.0), SRC), t)
            counters = {"samples": k + 1, "ticks": k + 1}
            if attitude_unused is not None:
                counters["attitude_unused"] = min(k + 1, attitude_unused)
            rec.write_estimate(_estimate(k, counters, imu_time))
    return path


def test_estimates_without_imu_time_are_not_called_no_estimates(tmp_path):
    path = _log(tmp_path / "noimu.mcap", N, imu_time=False)
    for said in (score_log(path)[0], _usage_error(path, tmp_path)):
        assert "holds no estimates" not in said and "fuse it first" not in said
        assert f"{N:,} estimates" in said and "no IMU" in said


def _usage_error(path: Path, tmp_path: Path) -> str:
    pytest.importorskip("matplotlib")
    with pytest.raises(UsageError) as caught:
        write_report(path, tmp_path / "out")
    return str(caught.value)


def test_a_score_against_the_attitude_the_fuser_took_says_it_is_circular(tmp_path):
    path = _log(tmp_path / "one10.mcap", None)
    lines = score_log(path)
    assert any("EKF3" in line for line in lines)
    note = " ".join(lines)
    assert f"fused {N:,} of the autopilot's {N:,} attitude samples" in note and "circular" in note
    assert "--no-attitude" in note


def test_a_score_where_the_attitude_was_left_unused_has_no_such_note(tmp_path):
    lines = score_log(_log(tmp_path / "one50.mcap", N))
    assert "circular" not in " ".join(lines)


def test_the_report_summary_says_it_too(tmp_path):
    pytest.importorskip("matplotlib")
    lines = write_report(_log(tmp_path / "one10.mcap", 0), tmp_path / "out")
    assert "circular" in " ".join(lines)
    assert "circular" in (tmp_path / "out" / "summary.md").read_text()


@pytest.mark.parametrize("unused, circular", [(None, True), (N, False)], ids=["attitude fused", "attitude unused"])
def test_the_batch_table_marks_a_circular_score_too(tmp_path, unused, circular):
    """The batch's error column said "2.08 vs EKF3" for a log whose EKF3 attitude the fuser had fused."""
    error_deg, reference, _ = batch._score(str(_log(tmp_path / "one10.mcap", unused)))
    assert error_deg is not None and reference == ("EKF3 (circular)" if circular else "EKF3")
