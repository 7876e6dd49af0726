"""Reports: PNGs and summary.md for a simulated and a real PX4 log; the summary's RMS figures against an
independent computation straight from the MCAP (mcap's reader, scipy's slerp), the reference named right."""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import chi2

pytest.importorskip("matplotlib")
from drivers.samples import AttitudeSample, SourceId  # noqa: E402
from fuser.config import load_config  # noqa: E402
from fuser.record import McapRecorder, read_log  # noqa: E402
from fuser.replay import replay  # noqa: E402
from fuser.report import reference_of, score_log, write_report  # noqa: E402

LOGS = Path(__file__).resolve().parent.parent / "logs"
PNGS = ("attitude.png", "error.png", "counters.png")


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR" and data[-8:-4] == b"IEND"
    return struct.unpack(">II", data[16:24])


def _rms_from_mcap(path: Path, since_s: float = 5.0) -> dict[str, float]:
    """RMS total, tilt and heading error of /estimate against /truth/pose, computed here from the raw MCAP; and, as
    ``inside 50`` etc., the percentage of estimates whose 50/90/95 % credible region holds the truth: for a
    concentrated Bingham ``-2 x^T C x`` of a draw is chi-square with 3 degrees of freedom (checked against an
    integral over the sphere in tests/test_evaluate.py), ``C = M diag(Z) M^T``."""
    est, ref, bingham = [], [], []
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=["/estimate", "/truth/pose"]):
            d = json.loads(message.data)
            if channel.topic == "/estimate":
                est.append((d["sensor_t_ns"], d["q_wxyz"], d["uncertainty_deg"]))
                bingham.append(np.array(d["M"]) @ np.diag(d["Z"]) @ np.array(d["M"]).T)
            else:
                o = d["pose"]["orientation"]
                ref.append((message.publish_time, [o["x"], o["y"], o["z"], o["w"]]))  # the vehicle's clock (fuser/IO.md)
    ref.sort()
    rt = np.array([t for t, _ in ref])
    keep = np.concatenate([[True], np.diff(rt) > 0])  # one reference per instant
    rt, rq = rt[keep], np.array([q for _, q in ref])[keep]
    et = np.array([t for t, _, _ in est])
    inside = (et >= rt[0]) & (et <= rt[-1])
    et = et[inside]
    eq = Rotation.from_quat(np.array([[q[1], q[2], q[3], q[0]] for _, q, _ in est])[inside])
    unc = np.array([u for _, _, u in est])[inside]
    r = Slerp((rt - rt[0]) * 1e-9, Rotation.from_quat(rq))((et - rt[0]) * 1e-9)
    total = np.degrees((eq * r.inv()).magnitude())
    down_e, down_r = eq.inv().apply([0, 0, 1]), r.inv().apply([0, 0, 1])  # world down seen from each body
    tilt = np.degrees(np.arccos(np.clip(np.sum(down_e * down_r, axis=1), -1, 1)))
    fe, fr = eq.apply([1, 0, 0]), r.apply([1, 0, 0])
    heading = np.degrees(np.abs(np.angle(np.exp(1j * (np.arctan2(fe[:, 1], fe[:, 0]) - np.arctan2(fr[:, 1], fr[:, 0]))))))
    late = (et - et[0]) >= since_s * 1e9
    q_true = r.as_quat()[:, [3, 0, 1, 2]]
    level = chi2.cdf(-2.0 * np.einsum("ni,nij,nj->n", q_true, np.array(bingham)[inside], q_true), 3)
    return {k: float(np.sqrt(np.mean(v[late] ** 2))) for k, v in
            (("total", total), ("tilt", tilt), ("heading", heading), ("uncertainty", unc))} | {
        f"inside {a:g}": 100.0 * float(np.mean(level[late] <= a / 100)) for a in (50, 90, 95)}


def _summary_rms(text: str) -> dict[str, float]:
    rms = {m[1]: float(m[2]) for m in re.finditer(r"^\| (total|tilt|heading|uncertainty) \| ([0-9.]+) \|$", text, re.MULTILINE)}
    return rms | {f"inside {m[1]}": float(m[2]) for m in re.finditer(r"^\| (50|90|95) % \| ([0-9.]+) % \|$", text, re.MULTILINE)}


def _check_report(log: Path, out: Path, reference: str) -> str:
    lines = write_report(log, out)
    for name in PNGS:
        width, height = _png_size(out / name)
        assert width >= 1000 and height >= 350, name
        assert (out / name).stat().st_size > 20_000, name  # not an empty canvas
    summary = (out / "summary.md").read_text()
    assert f"Reference: **{reference}**" in summary and lines[0].startswith(f"error against {reference} ")
    got, expected = _summary_rms(summary), _rms_from_mcap(log)
    assert set(got) == set(expected)
    for k in expected:
        tolerance = 0.051 if k.startswith("inside") else 0.0051  # the summary's rounding: one decimal in %, two in deg
        assert abs(got[k] - expected[k]) <= tolerance, (k, got[k], expected[k])
    return summary


def test_report_of_a_simulated_flight(tmp_path: Path) -> None:
    summary = _check_report(LOGS / "sim_hover.mcap", tmp_path, "simulator truth")
    assert any(line.endswith("% of the time (honest: about 50 / 90 / 95)") for line in score_log(LOGS / "sim_hover.mcap"))
    assert "ground truth" in summary and "| ticks | 1200 |" in summary


def test_report_of_the_px4_log_names_ekf2(tmp_path: Path) -> None:
    fused = tmp_path / "px4_fused.mcap"
    replay(LOGS / "px4_sample_cut.mcap", fused, load_config(LOGS / "px4_sample_cut.toml"), progress=None)
    summary = _check_report(fused, tmp_path / "report", "EKF2")
    assert "not ground truth" in summary
    assert any(line.startswith("  EKF2 inside the 50 / 90 / 95 % credible regions") and "agreement, not calibration" in line
               for line in score_log(fused))  # the autopilot's own error is in it: no "honest" figures to compare with
    assert read_log(fused).metadata["bingham_fuser"]["attribution"].startswith("PX4 flight log")  # carried by replay


def test_the_reference_is_named_from_metadata_or_source(tmp_path: Path) -> None:
    assert reference_of(read_log(LOGS / "broad_02_slow_rotation_cut.mcap")).name == "motion capture"
    src = SourceId("mavlink", 1, 1, 0)
    path = tmp_path / "ap.mcap"
    with McapRecorder(path, metadata={"source": "bingham-fuser run"}) as rec:
        rec.write_sample(AttitudeSample(1, (1.0, 0.0, 0.0, 0.0), src), 1)
    assert reference_of(read_log(path)).name == "autopilot attitude"
    with McapRecorder(path, metadata={"source": "ArduPilot DataFlash log"}) as rec:
        rec.write_truth(1, (1.0, 0.0, 0.0, 0.0))
    assert reference_of(read_log(path)).name == "EKF3"
