"""Batch replay (fuser/batch.py): many logs in processes or on Dask, the same bytes as one replay each.

The reference for every output file is ``fuser.replay.replay`` of that log alone, in this
process; counts are checked against the logs' own contents (messages on /input/*, packets
written into a .tlog with pymavlink), errors against the estimates the simulator recorded.
"""

import io
import multiprocessing as mp
import multiprocessing.connection
import os
import signal
import struct
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

os.environ.setdefault("MAVLINK20", "1")
from dask.distributed import LocalCluster  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from fuser import batch  # noqa: E402
from fuser.batch import BatchError, output_paths, run_batch  # noqa: E402
from fuser.cli import main  # noqa: E402
from fuser.config import FuserConfig  # noqa: E402
from fuser.record import INPUT_TOPICS, read_log  # noqa: E402
from fuser.replay import replay  # noqa: E402
from fuser.report import errors_of_log  # noqa: E402

LOGS = Path(__file__).resolve().parent.parent / "logs"
HOVER = LOGS / "sim_hover.mcap"


def write_tlog(path: Path, source: Path, count: int) -> int:
    """The first ``count`` IMU samples of an MCAP log as a .tlog of HIGHRES_IMU packets packed by pymavlink, after
    the autopilot's HEARTBEAT (which the fuser locks onto); returns the IMU packet count."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    imu = [(t, s) for s, t in read_log(source).inputs() if type(s).__name__ == "ImuSample"][:count]
    with open(path, "wb") as f:
        heartbeat = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)  # quadrotor, PX4, active
        f.write(struct.pack(">Q", imu[0][0] // 1000 - 1) + heartbeat.pack(mav))
        for i, (receive_ns, s) in enumerate(imu):
            mag = s.mag_gauss or (0.0, 0.0, 0.0)
            msg = mavlink.MAVLink_highres_imu_message(s.t_ns // 1000, *s.accel_m_s2, *s.gyro_rad_s, *mag, 0, 0, 0, 0,
                                                      0x3F | (0x1C0 if s.mag_gauss else 0), 0)
            mav.seq = (i + 1) % 256
            f.write(struct.pack(">Q", receive_ns // 1000) + msg.pack(mav))  # tlog: big-endian receive time in us, then the packet
    return len(imu)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """An MCAP log, a .tlog under the same stem, and a file that is no log."""
    d = tmp_path_factory.mktemp("logs")
    tlog = d / "sim_hover.tlog"  # same stem as logs/sim_hover.mcap
    packets = write_tlog(tlog, HOVER, 1000)  # 5 s at 200 Hz
    broken = d / "broken.mcap"
    broken.write_bytes(HOVER.read_bytes()[:100])  # the magic and half a header: no chunk survives
    return {"good": [HOVER, tlog], "tlog": tlog, "tlog_packets": packets, "broken": broken, "all": [HOVER, tlog, broken]}


@pytest.fixture(scope="module")
def reference(logs, tmp_path_factory):
    """Each log replayed alone by fuser.replay, in this process."""
    d = tmp_path_factory.mktemp("reference")
    out = {}
    for log in logs["good"]:
        out[log] = d / f"{log.stem}_{log.suffix[1:]}.mcap"
        replay(log, out[log], FuserConfig(), progress=None)
    return out


@pytest.fixture(scope="module")
def local(logs, tmp_path_factory):
    """The batch with --jobs 1 (in this process)."""
    return run_batch(logs["all"], tmp_path_factory.mktemp("jobs1"), FuserConfig(), jobs=1)


def test_output_names_are_deterministic_and_distinct():
    names = [p.name for p in output_paths(["a/x.mcap", "b/x.tlog", "c/X.mcap", "d/x-2.mcap", "y.mcap"], "out")]
    assert names == ["x.mcap", "x-2.mcap", "X-3.mcap", "x-2-2.mcap", "y.mcap"]


def test_an_output_that_would_overwrite_an_input_is_refused(tmp_path, capsys):
    log = tmp_path / "flight.mcap"
    log.write_bytes(HOVER.read_bytes())
    with pytest.raises(BatchError, match="overwrite"):
        run_batch([log], tmp_path, FuserConfig())
    assert main(["replay", str(log), "--out-dir", str(tmp_path)]) == 2
    assert "overwrite" in capsys.readouterr().err
    assert log.read_bytes() == HOVER.read_bytes()


def test_jobs_2_writes_the_bytes_of_jobs_1_and_of_single_replays(logs, reference, local, tmp_path):
    two = run_batch(logs["all"], tmp_path / "two", FuserConfig(), jobs=2)
    assert [Path(r.output).name for r in local] == [Path(r.output).name for r in two] == \
        ["sim_hover.mcap", "sim_hover-2.mcap", "broken.mcap"]
    assert [r.ok for r in local] == [r.ok for r in two] == [True, True, False]
    for r1, r2, log in zip(local, two, logs["good"]):
        expected = reference[log].read_bytes()
        assert Path(r1.output).read_bytes() == expected
        assert Path(r2.output).read_bytes() == expected


def test_an_autopilots_estimate_is_named_as_the_reference_not_called_truth(tmp_path):
    """The PX4 cut's reference is EKF2's attitude (its metadata says so): the summary says "vs EKF2", as ``report``
    does, so agreement with another estimator is not read as accuracy."""
    (result,) = run_batch([LOGS / "px4_sample_cut.mcap"], tmp_path, FuserConfig(), jobs=1)
    assert result.ok and result.reference == "EKF2" and result.error_deg is not None
    assert any(line.endswith(f"{result.error_deg:.2f} vs EKF2") for line in batch.format_summary([result]))


def test_a_dataflash_log_cut_short_is_replayed_and_the_summary_says_what_its_import_left(tmp_path):
    """A fleet's .BIN goes through the batch as it is (imported on the way, fuser/replay.py); one cut 5 bytes into
    its last record: the summary names the log and the bytes, as ``import`` would."""
    from dataflash_writer import DataFlashWriter

    w = DataFlashWriter()
    w.declare(76, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    for k in range(400):
        w.write("IMU", TimeUS=1_000_000 + 5_000 * k, I=0, GyrX=0.0, GyrY=0.0, GyrZ=0.0, AccX=0.0, AccY=0.0, AccZ=-9.80665,
                EG=0, EA=0, T=40.0, GH=1, AH=1, GHz=1000, AHz=1000)
    (tmp_path / "cut.BIN").write_bytes(bytes(w.data[: w.last_record_at + 5]))
    (result,) = run_batch([tmp_path / "cut.BIN"], tmp_path / "out", FuserConfig(), jobs=1)
    assert result.ok and result.samples == 399 and result.not_imported == {"incomplete_tail_bytes": 5}
    assert f"{tmp_path / 'cut.BIN'}: not imported: incomplete_tail_bytes=5 (the log was cut short, or ends in garbage)" in batch.format_summary([result])


def test_summary_counts_and_errors(logs, tmp_path):
    inputs = [HOVER, logs["tlog"], logs["broken"], tmp_path / "missing.tlog"]
    results = run_batch(inputs, tmp_path / "out", FuserConfig(), jobs=1)
    hover, tlog, broken, missing = results
    stored = read_log(HOVER)
    assert hover.samples == hover.accepted == len(stored.of(INPUT_TOPICS))
    assert hover.estimates == len(read_log(hover.output).estimates())
    # the simulator's own run recorded estimates into the log; its error against the truth is the replay's
    recorded = errors_of_log(HOVER)[1].rms(5.0)["total"]
    assert hover.reference == "simulator truth" and hover.error_deg == pytest.approx(recorded, abs=1e-6)
    assert tlog.ok and tlog.samples == logs["tlog_packets"] and tlog.error_deg is None  # a .tlog of IMU only: no reference
    assert not broken.ok and "nothing to replay" in broken.reason and "no record could be read" in broken.reason
    assert not Path(broken.output).exists()
    assert not missing.ok and missing.reason == "no such log file"
    folder = batch.run_task(batch.LogTask(str(tmp_path), str(tmp_path / "folder.mcap"), FuserConfig()))
    assert not folder.ok and folder.reason == "a folder, not a log file"
    lines = batch.format_summary(results, wall_s=2.0)
    assert len(lines) == 6 and "\n" not in "".join(lines)
    assert lines[1].split()[:3] == [str(HOVER), "ok", f"{hover.samples:,}"]
    assert lines[3].split()[1] == "failed"
    assert lines[-1].startswith("replay: 4 logs, 2 ok, 2 failed;")


def test_progress_bar_only_on_a_terminal(tmp_path):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    pipe, tty = io.StringIO(), Terminal()
    run_batch([HOVER, tmp_path / "missing.mcap"], tmp_path / "a", FuserConfig(), progress=pipe)
    run_batch([HOVER, tmp_path / "missing.mcap"], tmp_path / "b", FuserConfig(), progress=tty)
    assert pipe.getvalue() == ""
    assert "2/2" in tty.getvalue() and "failed=1" in tty.getvalue()


def test_cli_batch_exit_status_and_table(logs, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["replay", str(HOVER), str(logs["tlog"]), "--out-dir", str(out), "--jobs", "1"]) == 0
    text = capsys.readouterr().out
    assert "replay: 2 logs, 2 ok, 0 failed" in text
    assert sorted(p.name for p in out.iterdir()) == ["sim_hover-2.mcap", "sim_hover.mcap"]
    assert main(["replay", str(HOVER), str(logs["broken"]), "--out-dir", str(out), "--jobs", "1"]) == 1
    assert "1 failed" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["replay", str(HOVER), str(HOVER), "-o", "x.mcap"], "-o is for one log"),
        (["replay", str(HOVER), "-o", "x.mcap", "--jobs", "2"], "need --out-dir"),
        (["replay", str(HOVER), str(HOVER)], "--out-dir DIR"),
        (["replay", str(HOVER), "--out-dir", "d", "--jobs", "0"], "expected a whole number of at least 1"),
        (["replay", str(HOVER), "--out-dir", "d", "--jobs", "2", "--dask", "tcp://127.0.0.1:1"], "not allowed with"),
    ],
)
def test_cli_argument_errors_are_one_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


def test_missing_dask_names_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import dask.distributed now raises ImportError
    assert main(["replay", str(HOVER), "--out-dir", str(tmp_path), "--dask", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "replay: --dask needs dask.distributed: pip install 'bingham-fuser[cluster]'"


def test_unreachable_scheduler_is_one_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(batch, "DASK_CONNECT_TIMEOUT_S", 0.5)
    with socket_port() as port:  # a port that is bound but never accepts: nothing listens for Dask there
        assert main(["replay", str(HOVER), "--out-dir", str(tmp_path), "--dask", f"tcp://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("replay: cannot reach the Dask scheduler at tcp://127.0.0.1:")


class socket_port:
    def __enter__(self):
        import socket

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        return self.sock.getsockname()[1]

    def __exit__(self, *exc):
        self.sock.close()


def test_dask_cluster_writes_the_bytes_of_the_local_run(logs, reference, local, tmp_path):
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        results = run_batch(logs["all"], tmp_path / "dask", FuserConfig(), dask_address=cluster.scheduler_address)
    assert [r.ok for r in results] == [True, True, False]
    assert [Path(r.output).name for r in results] == [Path(r.output).name for r in local]
    assert "nothing to replay" in results[2].reason
    for r, lr, log in zip(results, local, logs["good"]):
        assert Path(r.output).read_bytes() == Path(lr.output).read_bytes() == reference[log].read_bytes()
        assert (r.samples, r.estimates, r.accepted, r.rejected, r.error_deg) == (lr.samples, lr.estimates, lr.accepted, lr.rejected, lr.error_deg)


def _worker_pids() -> list[int]:
    """This process's ProcessPoolExecutor workers (spawned: their command line runs spawn_main)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (entry / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == os.getpid() and b"spawn_main" in cmdline:
            pids.append(int(entry.name))
    return pids


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the worker processes through /proc")
def test_a_killed_worker_costs_no_log(logs, reference, tmp_path):
    """A worker killed from outside breaks the whole pool; every log it took down is replayed again, alone."""
    inputs = logs["good"]
    results: list = []
    thread = threading.Thread(target=lambda: results.extend(run_batch(inputs, tmp_path / "out", FuserConfig(), jobs=2)))
    thread.start()
    deadline = time.monotonic() + 30
    while not (pids := _worker_pids()) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pids, "no worker process appeared"
    os.kill(pids[0], signal.SIGKILL)
    thread.join(600)  # the pool is rebuilt and the logs replayed again: a minute on a loaded 2-core machine
    assert not thread.is_alive(), "the batch did not finish after its worker was killed"
    assert [r.ok for r in results] == [True, True], [r.reason for r in results]
    for r, log in zip(results, inputs):
        assert Path(r.output).read_bytes() == reference[log].read_bytes()


def test_a_worker_that_dies_while_the_pool_starts_the_others_costs_no_log(logs, reference, tmp_path, monkeypatch):
    """The killed-worker test once failed so in a clean clone: the worker was killed while the pool was spawning
    the second, and submit raised ``OSError: handle is closed`` out of run_batch. Here the second submit raises it
    every time: that log is replayed alone, like one a dying worker took down."""
    real = batch.ProcessPoolExecutor

    class BreaksWhileStarting(real):  # type: ignore[misc, valid-type]
        pools = 0

        def __init__(self, *args, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            BreaksWhileStarting.pools += 1
            self._first_pool, self._submitted = BreaksWhileStarting.pools == 1, 0

        def submit(self, *args, **kwargs):
            self._submitted += 1
            if self._first_pool and self._submitted == 2:
                raise OSError("handle is closed")
            return super().submit(*args, **kwargs)

    monkeypatch.setattr(batch, "ProcessPoolExecutor", BreaksWhileStarting)
    inputs = logs["good"]
    results = run_batch(inputs, tmp_path / "out", FuserConfig(), jobs=2)
    assert [r.ok for r in results] == [True, True], [r.reason for r in results]
    assert BreaksWhileStarting.pools == 2  # the pool, and the one the broken log ran alone in
    for r, log in zip(results, inputs):
        assert Path(r.output).read_bytes() == reference[log].read_bytes()


def test_a_broken_pools_workers_are_stopped_so_its_shutdown_cannot_wait_for_them():
    """The killed-worker test hung once in a clean clone: pytest-timeout's stacks showed the pool's manager thread
    joining a worker forever and the batch waiting in the pool's shutdown (in Python 3.11 a worker that a submit
    spawns while the pool breaks is recorded after the pool's clean-up has terminated the others). The batch now
    stops every worker the pool holds before shutting it down: here two busy workers, stopped, and the shutdown
    returns at once instead of after their 60 s."""
    with ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("spawn")) as pool:
        futures = [pool.submit(time.sleep, 60.0) for _ in range(2)]
        deadline = time.monotonic() + 60
        while len(pool._processes) < 2 and time.monotonic() < deadline:  # both spawned
            time.sleep(0.01)
        workers = list(pool._processes.values())
        assert len(workers) == 2
        start = time.monotonic()
        batch._stop_workers(pool)
        assert all(mp.connection.wait([w.sentinel], 10) for w in workers)  # exited (the pool's thread reaps them)
    assert time.monotonic() - start < 30
    assert all(f.done() for f in futures)


def test_what_a_killed_worker_left_beside_its_output_is_removed_before_its_log_is_replayed_again(tmp_path):
    """A replay killed from outside leaves its partial output (``.OUT.mcap.PID.partial``) and, for a log imported
    on the way, its temporary import (``.STEM.import.XXXX/``); a fleet's out-dir would fill with them. Exactly
    those go, not another log's (a name that only begins the same, or brackets that a glob would read)."""
    out = tmp_path / "out"
    out.mkdir()
    mine = [out / ".f[1].mcap.4242.partial", out / ".f[1].import.abcd"]
    others = [out / ".f[1]x.mcap.4242.partial", out / ".f1.mcap.4242.partial", out / ".g.import.abcd", out / "f[1].mcap"]
    mine[0].write_bytes(b"half a log")
    mine[1].mkdir()
    (mine[1] / "f[1].mcap").write_bytes(b"an import")
    for path in others:
        path.write_bytes(b"keep")
    task = batch.LogTask(str(tmp_path / "f[1].BIN"), str(out / "f[1].mcap"), FuserConfig())
    batch._remove_leftovers(task)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in others)


def test_a_reference_outside_the_flight_scores_nothing_and_fails_nothing(tmp_path):
    """Truth recorded 1000 s after the flight (another clock): the log replays, with no error to report."""
    from fuser.record import McapRecorder

    log = tmp_path / "late_truth.mcap"
    stored = read_log(HOVER)
    with McapRecorder(log) as rec:
        for m in stored.of(INPUT_TOPICS):
            rec.write_message(*m)
        for t_ns, q in stored.truth():
            rec.write_truth(t_ns + 1_000_000_000_000, q)
    result, = run_batch([log], tmp_path / "out", FuserConfig())
    assert result.ok, result.reason
    assert result.samples == len(stored.of(INPUT_TOPICS)) and result.error_deg is None and result.reference is None
