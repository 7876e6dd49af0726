"""``bingham-fuser import``: frame and unit conversions, and real-data cuts replayed through the CLI.

The cuts in ``logs/`` are real sensor data (BROAD, CC-BY-4.0, Laidig et al. 2021; PX4 sample.ulg,
BSD-3-Clause; see ``logs/README.md``). Reference values are computed here independently of the code
under test: explicit rotation matrices instead of the importer's quaternion products, tilt from the
accelerometer by the textbook roll/pitch formulas, errors by the angle between unit quaternions.
Tests that read ``../shared/data`` skip when it is absent.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from core import quaternion as quat
from drivers.euler import euler_from_quaternion
from drivers.samples import AttitudeSample, ImuSample
from fuser.importers import broad_quat_from_ned, broad_quat_to_ned, broad_vectors_to_frd, field_from_rest
from fuser.record import read_log

from log_order import order_violations

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT / "logs"
BROAD_CUT = LOGS / "broad_02_slow_rotation_cut.mcap"
PX4_CUT = LOGS / "px4_sample_cut.mcap"
SHARED = ROOT.parent / "shared" / "data"
BROAD_TRIAL = SHARED / "broad" / "02_undisturbed_slow_rotation_B.hdf5"

# explicit matrices, written down from the frame definitions (not from the importer)
S_TO_FRD = np.diag([1.0, -1.0, -1.0])  # sensor (x fwd, y left, z up) -> FRD
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
BROAD_REST_S = 3.5  # the cut starts 4 s before BROAD's movement phase
BROAD_BOUND_DEG = 3.0  # measured 1.7 deg RMS total on this cut (default FuserConfig, Nov 2025)
PX4_BOUND_DEG = 2.5  # measured 0.53 deg RMS total difference to EKF2 after 5 s


def _angle_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    dot = np.abs(np.sum(quat.normalize(p) * quat.normalize(q), axis=-1))
    return np.degrees(2 * np.arccos(np.clip(dot, 0.0, 1.0)))


# -- conversions without data -------------------------------------------------------------------
def test_level_sensor_at_rest_reads_minus_g_in_frd():
    f_s = np.array([[0.0, 0.0, 9.81]])  # BROAD sensor lying flat: specific force points up (+z)
    np.testing.assert_allclose(broad_vectors_to_frd(f_s), [[0.0, 0.0, -9.81]], atol=1e-12)


def test_vectors_match_explicit_matrix():
    v = np.random.default_rng(1).normal(size=(50, 3))
    np.testing.assert_allclose(broad_vectors_to_frd(v), v @ S_TO_FRD.T, atol=1e-12)


def test_sensor_aligned_with_enu_is_level_and_faces_east():
    # q_ES = identity: sensor x (forward) = east, z = up -> FRD level, yaw +90 deg (east of north)
    roll, pitch, yaw = euler_from_quaternion(tuple(broad_quat_to_ned(np.array([[1.0, 0, 0, 0]]))[0]))
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9
    assert yaw == pytest.approx(math.pi / 2, abs=1e-9)


def test_quaternion_conversion_matches_matrices_and_round_trips():
    rng = np.random.default_rng(2)
    q_es = quat.normalize(rng.normal(size=(40, 4)))
    v_s = rng.normal(size=(40, 3))
    q_nb = broad_quat_to_ned(q_es)
    v_ned_expected = (ENU_TO_NED @ quat.rotate(q_es, v_s)[..., None])[..., 0]
    np.testing.assert_allclose(quat.rotate(q_nb, broad_vectors_to_frd(v_s)), v_ned_expected, atol=1e-12)
    assert np.max(_angle_deg(broad_quat_from_ned(q_nb), q_es)) < 1e-5


def test_field_from_rest_recovers_norm_and_dip():
    dip = math.radians(66.0)
    q = quat.normalize(np.array([0.95, 0.1, -0.2, 0.3]))  # some attitude, body FRD -> NED
    field_ned = 0.48 * np.array([math.cos(dip), 0.0, math.sin(dip)])
    body = lambda v: quat.rotate(quat.conjugate(q), v)  # noqa: E731
    accel = np.tile(body(np.array([0.0, 0.0, -9.81])), (10, 1))
    mag = np.tile(body(field_ned), (10, 1))
    np.testing.assert_allclose(field_from_rest(accel, mag), field_ned, atol=1e-9)
    # readings too weak to be a reference (a magnetometer that sends zeros or denormals) are not averaged in
    weak = mag.copy()
    weak[:5] = 1e-300
    np.testing.assert_allclose(field_from_rest(accel, weak), field_ned, atol=1e-9)
    assert field_from_rest(accel, np.full_like(mag, 1e-300)) is None


# -- the cuts in logs/ ----------------------------------------------------------------------------
def _cut(path: Path):
    contents = read_log(path)
    assert contents.complete
    imu = [s for s, _ in contents.inputs() if isinstance(s, ImuSample)]
    truth = contents.truth()
    return contents, imu, np.array([t for t, _ in truth]), np.array([q for _, q in truth])


def test_broad_cut_is_real_286hz_data_in_gauss_with_attribution():
    contents, imu, t_ref, _ = _cut(BROAD_CUT)
    assert BROAD_CUT.stat().st_size < 2_000_000
    meta = contents.metadata["bingham_fuser"]
    assert "CC-BY-4.0" in meta["attribution"] and "Laidig" in meta["attribution"]
    dt = np.diff([s.t_ns for s in imu])
    assert np.all(dt == 3_500_000)  # 285.714 Hz is exactly 3500 us
    norms = np.linalg.norm([s.mag_gauss for s in imu], axis=1)
    assert 0.35 < np.median(norms) < 0.55  # Berlin lab field ~44 uT = 0.44 G
    assert len(t_ref) == len(imu)


def test_broad_cut_truth_agrees_with_accelerometer_and_magnetometer_at_rest():
    _, imu, t_ref, q_ref = _cut(BROAD_CUT)
    t = np.array([s.t_ns for s in imu])
    rest = (t - t[0]) < BROAD_REST_S * 1e9
    acc = np.array([s.accel_m_s2 for s in imu])[rest].mean(axis=0)
    mag = np.array([s.mag_gauss for s in imu])[rest].mean(axis=0)
    q = quat.normalize(q_ref[rest].mean(axis=0))  # attitude barely changes at rest
    # independent attitude from the accelerometer: FRD roll and pitch (f = R^T (0, 0, -g))
    roll_acc = math.atan2(-acc[1], -acc[2])
    pitch_acc = math.atan2(acc[0], math.hypot(acc[1], acc[2]))
    roll, pitch, _ = euler_from_quaternion(tuple(q))
    assert math.degrees(abs(roll - roll_acc)) < 1.0
    assert math.degrees(abs(pitch - pitch_acc)) < 1.0
    # the converted accelerometer, rotated by the converted truth, reads -g along NED down
    np.testing.assert_allclose(quat.rotate(q, acc), [0.0, 0.0, -9.81], atol=0.25)
    # the field in NED points to magnetic north and down (BROAD's ENU is the magnetometer's)
    m = quat.rotate(q, mag)
    assert abs(math.degrees(math.atan2(m[1], m[0]))) < 3.0 and m[2] > 0


def test_px4_cut_carries_ekf2_reference_and_attitude_stream():
    contents, imu, t_ref, q_ref = _cut(PX4_CUT)
    assert PX4_CUT.stat().st_size < 2_000_000
    meta = contents.metadata["bingham_fuser"]
    assert "EKF2" in meta["reference"] and "NOT ground truth" in meta["reference"]
    att = [s for s, _ in contents.inputs() if isinstance(s, AttitudeSample)]
    assert len(att) == len(t_ref) > 1000
    np.testing.assert_allclose([a.q_wxyz for a in att], q_ref, atol=1e-6)  # float32 through MAVLink
    rate = (len(imu) - 1) / ((imu[-1].t_ns - imu[0].t_ns) * 1e-9)
    assert 230 < rate < 260
    # PX4 is already FRD/NED: once still (after ~7 s) the accelerometer reads about -g down
    t = np.array([s.t_ns for s in imu])
    still = (t - t[0]) > 10e9
    i = np.searchsorted(t_ref, t[still]).clip(0, len(t_ref) - 1)
    f_ned = quat.rotate(quat.normalize(q_ref[i]), np.array([s.accel_m_s2 for s in imu])[still]).mean(axis=0)
    np.testing.assert_allclose(f_ned, [0.0, 0.0, -9.8], atol=0.3)


def _replay(cut: Path, tmp_path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    out = tmp_path / (cut.stem + "_fused.mcap")
    cmd = [sys.executable, "-m", "fuser.cli", "replay", str(cut), "-o", str(out), "--config", str(cut.with_suffix(".toml"))]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    contents = read_log(out)
    est = [e for e in contents.estimates() if e.sensor_t_ns is not None]
    truth = contents.truth()
    return (np.array([e.sensor_t_ns for e in est]), np.array([e.q_wxyz for e in est]),
            np.array([t for t, _ in truth]), np.array([q for _, q in truth]))


def _errors_after(t, q, t_ref, q_ref, since_s: float) -> np.ndarray:
    keep = (t - t_ref[0] >= since_s * 1e9) & (t <= t_ref[-1])
    i = np.searchsorted(t_ref, t[keep]).clip(1, len(t_ref) - 1)
    nearest = np.where(t[keep] - t_ref[i - 1] < t_ref[i] - t[keep], i - 1, i)
    return _angle_deg(q[keep], q_ref[nearest])


def test_broad_cut_replays_within_bound_of_optical_truth(tmp_path):
    t, q, t_ref, q_ref = _replay(BROAD_CUT, tmp_path)
    assert len(t) > 2000  # 24 s at 100 Hz
    err = _errors_after(t, q, t_ref, q_ref, since_s=4.0)  # the movement phase of the cut
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < BROAD_BOUND_DEG, f"RMS {rms:.2f} deg against the optical truth"
    # the bound discriminates: a 5 deg yaw error in the convention would break it
    yawed = quat.multiply(np.broadcast_to(quat.from_rotvec([0, 0, math.radians(5)]), q.shape), q)
    assert float(np.sqrt(np.mean(_errors_after(t, yawed, t_ref, q_ref, 4.0) ** 2))) > rms + 2.0


def test_px4_cut_replays_close_to_ekf2(tmp_path):
    t, q, t_ref, q_ref = _replay(PX4_CUT, tmp_path)
    err = _errors_after(t, q, t_ref, q_ref, since_s=5.0)
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < PX4_BOUND_DEG, f"RMS {rms:.2f} deg against EKF2"


# -- the command on the shared data (skipped on a user's machine) -----------------------------------
needs_broad = pytest.mark.skipif(not BROAD_TRIAL.exists(), reason="../shared/data/broad not available")


@needs_broad
def test_import_command_reproduces_the_cut_from_the_hdf5(tmp_path):
    pytest.importorskip("h5py")
    import h5py

    out = tmp_path / "cut.mcap"
    cmd = [sys.executable, "-m", "fuser.cli", "import", str(BROAD_TRIAL), "-o", str(out), "--start", "36", "--duration", "24"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    assert out.read_bytes() == BROAD_CUT.read_bytes()  # deterministic: the committed cut is this command's output
    assert out.with_suffix(".toml").read_text().split("\n", 1)[1] == BROAD_CUT.with_suffix(".toml").read_text().split("\n", 1)[1]
    # raw hdf5 vs decoded sample: explicit matrix, uT -> gauss, float32 precision of MAVLink
    with h5py.File(BROAD_TRIAL) as f:
        i = int(round(36 * f.attrs["sampling_rate"])) + 100
        acc, mag = f["imu_acc"][i], f["imu_mag"][i]
    s = [x for x, _ in read_log(out).inputs()][100]
    np.testing.assert_allclose(s.accel_m_s2, S_TO_FRD @ acc, rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(s.mag_gauss, S_TO_FRD @ mag * 0.01, rtol=1e-6, atol=1e-7)


PX4_LOG = SHARED / "px4" / "sample.ulg"


@pytest.mark.skipif(not PX4_LOG.exists(), reason="../shared/data/px4 not available")
def test_import_writes_every_record_in_log_time_order(tmp_path):
    """Inputs and reference interleaved in time, not in separate passes (19,379 records out of order on sample.ulg:
    every /truth/pose and its /tf after the inputs, and each attitude, whose message carries milliseconds, behind
    the IMU sample sent with it); the records themselves as before."""
    pytest.importorskip("pyulog")
    from fuser.importers import import_log

    s = import_log(PX4_LOG, tmp_path / "sample.mcap")
    assert order_violations(tmp_path / "sample.mcap") == {}
    contents = read_log(tmp_path / "sample.mcap")
    assert (s.imu, s.attitude, s.truth) == (17070, 6460, 6460)
    assert [len(contents.of([t])) for t in ("/input/imu", "/input/attitude", "/truth/pose", "/tf")] == [17070, 6460, 6460, 6460]


@pytest.mark.parametrize("log", [BROAD_TRIAL, PX4_LOG], ids=lambda p: p.suffix)
def test_a_window_after_the_logs_end_is_one_usage_error_naming_its_length(log, tmp_path):
    """It wrote an MCAP of nothing (the fallback field printed as if measured), exit 0; the replay then failed. The
    length is the reader's own: BROAD's sample count over its rate, the ULog's sensor_combined span."""
    if not log.exists():
        pytest.skip("../shared/data not available")
    from fuser.errors import UsageError
    from fuser.importers import import_log

    if log.suffix == ".hdf5":
        h5py = pytest.importorskip("h5py")
        with h5py.File(log) as f:
            length_s = (len(f["imu_gyr"]) - 1) / float(f.attrs["sampling_rate"])
    else:
        t_us = pytest.importorskip("pyulog").ULog(str(log), ["sensor_combined"]).get_dataset("sensor_combined").data["timestamp"]
        length_s = (int(t_us.max()) - int(t_us.min())) / 1e6
    with pytest.raises(UsageError, match=rf"^nothing in {re.escape(str(log))} from --start 1e\+09 s for --duration 5 s: "
                                         rf"the log holds {length_s:.1f} s of IMU data$"):
        import_log(log, tmp_path / "o.mcap", start_s=1e9, duration_s=5.0)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("cut", [BROAD_CUT, PX4_CUT], ids=lambda p: p.stem)
def test_committed_cuts_are_in_log_time_order(cut):
    assert order_violations(cut) == {}


def test_import_rejects_unknown_format(tmp_path):
    bogus = tmp_path / "x.csv"
    bogus.write_text("1,2,3\n")
    run = subprocess.run([sys.executable, "-m", "fuser.cli", "import", str(bogus), "-o", str(tmp_path / "o.mcap")],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert run.returncode == 2 and "BROAD" in run.stderr


def test_replaying_a_log_whose_reader_is_not_installed_names_the_extra(tmp_path, monkeypatch, capsys):
    """``replay x.ulg`` imports on the way; without pyulog that is one line saying what to install, exit 2, and
    no output (and no temporary import) left behind."""
    import importlib.util

    from fuser.cli import main

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *args: None if name == "pyulog" else find_spec(name, *args))
    (tmp_path / "flight.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + bytes(8))
    assert main(["replay", str(tmp_path / "flight.ulg"), "-o", str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["bingham-fuser: reading px4 logs needs the 'pyulog' package: pip install 'bingham-fuser[import]' (or pip install pyulog)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.ulg"]
