"""Fuser performance: replay throughput and live publish latency, against the issue's targets.

    python benchmarks/bench_fuser.py            # all three, prints one table (about two minutes)
    python benchmarks/bench_fuser.py --skip-live --skip-replay   # the per-message costs only
    python benchmarks/bench_fuser.py --profile  # and where replay time goes (cProfile)
    python benchmarks/bench_fuser.py --baseline main --skip-live --skip-messages   # replay and per tick, REF beside this tree
    python benchmarks/bench_fuser.py --skip-live --skip-messages --ticks-only     # replay without the output predictor

(a) Replay throughput, end to end: decode every input from the MCAP, run the
    loop, write inputs and estimates to a new MCAP; IMU samples per second of
    wall time on one core (fastest of three runs), for each log in logs/ and a
    400 Hz simulated flight; beside it the model's cost per tick on the same
    log (``benchmarks/bench_tick.py``: the model and the wire estimate alone,
    fastest of three runs).
    Targets (issue 17): >= 20,000 IMU samples/s; <= 25 us per tick.
(b) Live latency: 400 Hz HIGHRES_IMU over UDP from a sender process
    (`bingham-fuser sim --send`), the 100 Hz loop and a 400 Hz one
    (``--live-loop-hz``), estimates published on zenoh to a subscriber process;
    latency from each estimate's due time (a tick's, or the output predictor's
    sample arrival) to its hand-over to zenoh (LiveRunner's own measurement),
    p50/p99/max, and overruns. Targets (issue 17): p99 < 1 ms at 100 Hz, < 2 ms
    at 400 Hz.
(c) Cost per message of each I/O step of a replay, on the inputs of every log in
    logs/ (and the estimates the simulated ones hold), fastest of five passes, each
    beside the decode floor: bare pymavlink ``parse_buffer`` on the same samples
    as MAVLink 2 bytes (one packet per call, as datagrams arrive):
    MavlinkDecoder.feed of those bytes, ``dumps`` of a sample and of an estimate
    (and its /pose), McapRecorder.write_message, read_log and decode_sample; and
    VQF (``updateBatch``, the ``bench`` extra) on the same IMU samples.

Every replay row stands beside the decode floor on that log's bytes and VQF on
its samples, measured in the same run, so a loaded machine shows in all three.
``--baseline REF`` replays the same logs with the code of a git revision (a
temporary detached worktree, its own numba caches warmed by the first of its
runs) just before and just after this tree's runs on each log, for before/after
figures on a shared machine.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(os.environ.get("BENCH_CODE_ROOT") or Path(__file__).resolve().parent.parent)
"""The tree whose code is measured: this one, or a ``--baseline`` revision's worktree (set by the parent run)."""
sys.path.insert(0, str(ROOT))

from drivers.mavlink_decode import MavlinkDecoder, dialect_module  # noqa: E402
from drivers.mavlink_encode import MavlinkEncoder  # noqa: E402
from drivers.samples import AttitudeSample, GnssSample, ImuSample, Sample  # noqa: E402
from drivers.sim import SimConfig, simulate  # noqa: E402
from fuser.codec import Estimate, decode_sample, dumps, loads, sample_json  # noqa: E402
from fuser.config import FuserConfig, ZenohSettings  # noqa: E402
from fuser.pipeline import Pipeline  # noqa: E402
from fuser.record import INPUT_TOPICS, McapRecorder, RawMessage, pose_in_frame, read_log  # noqa: E402
from fuser.replay import replay  # noqa: E402
from fuser.simulate import run_sim  # noqa: E402

from bench_tick import TICK_TARGET_US, baseline_tree, captured_ticks, run_ticks  # noqa: E402
from bench_tick import config_for as log_config  # noqa: E402

REPLAY_TARGET = 20_000.0
LATENCY_P99_TARGET_MS = {100.0: 1.0, 400.0: 2.0}
"""The issue's p99 budget by loop rate (Hz): 1 ms at the default 100 Hz, 2 ms at a 400 Hz loop."""
PASSES = 5
"""Per-message costs are the fastest of this many passes over all the messages."""
VQF_MISSING = "vqf not installed: pip install -e '.[bench]'"
"""Per-message costs are the fastest of this many passes over all the messages."""


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def sim_log(path: Path, seconds: float, imu_hz: float) -> None:
    """A simulated flight's inputs (as the fuser receives them) and truth, recorded to MCAP."""
    with McapRecorder(path) as rec:
        pipeline = Pipeline(FuserConfig(), [rec.write_sample], [])
        run_sim(pipeline, simulate(SimConfig(duration_s=seconds, imu_rate_hz=imu_hz)), "mavlink", 0, [rec.write_truth])


TICKS_ONLY_ENV = "BENCH_TICKS_ONLY"
"""Set (by ``--ticks-only``, for this process and a ``--baseline`` child): replay with one estimate per tick."""


def config_for(log: Path) -> FuserConfig:
    """The settings a log is replayed with (:func:`bench_tick.config_for`); with ``--ticks-only``, the output
    predictor off (``[fuser.extrapolation] every_imu_sample = false``)."""
    config = log_config(log)
    return config.replace(extrapolation={"every_imu_sample": False}) if os.environ.get(TICKS_ONLY_ENV) else config


def bench_replay(log: Path, out: Path, repeats: int = 3) -> dict:
    """The fastest of ``repeats`` replays (as timeit does): on a shared machine the slower runs
    measure the other jobs, and one run of a 12 s log varies by 15%."""
    imu = len(read_log(log).of(["/input/imu"]))
    config = config_for(log)
    fastest = min((replay(log, out, config, progress=None) for _ in range(repeats)), key=lambda s: s.seconds)
    ticks = captured_ticks(log, config)
    tick_us = min(run_ticks(config, ticks) for _ in range(repeats)) / len(ticks) * 1e6
    return {"imu": imu, "samples": fastest.samples, "seconds": fastest.seconds, "imu_per_s": imu / fastest.seconds, "tick_us": tick_us}


def bench_baseline(tree: Path, log: Path) -> dict:
    """:func:`bench_replay` of ``log`` with the code of the worktree ``tree`` (another revision), in a child process."""
    out = subprocess.run([sys.executable, __file__, "--replay-json", str(log)], cwd=tree, check=True, capture_output=True, text=True,
                         env={**os.environ, "BENCH_CODE_ROOT": str(tree)})
    return json.loads(out.stdout.strip().splitlines()[-1])[str(log)]


def profile_replay(log: Path, out: Path, top: int = 18) -> str:
    prof = cProfile.Profile()
    prof.enable()
    replay(log, out, FuserConfig(), progress=None)
    prof.disable()
    text = io.StringIO()
    stats = pstats.Stats(prof, stream=text).strip_dirs()
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top + 12)
    return text.getvalue()


def bench_live(seconds: float, imu_hz: float, record: Path | None = None, loop_hz: float = 100.0) -> dict:
    """LiveRunner wired as `bingham-fuser run [--record]` wires it, fed by a sender process, publishing to a subscriber process."""
    from drivers.sources import MavlinkSource
    from fuser.live import LiveRunner
    from fuser.publish import ZenohPublisher, zenoh_config
    from fuser.record import RecorderProcess

    udp, zport = free_port(socket.SOCK_DGRAM), free_port()
    endpoint = f"tcp/127.0.0.1:{zport}"
    config = FuserConfig(vehicle="bench", rate_hz=loop_hz, zenoh=ZenohSettings(listen=(endpoint,)))
    source = MavlinkSource(f"udpin:127.0.0.1:{udp}")
    pub = ZenohPublisher(zenoh_config(list(config.zenoh.listen), []), config.vehicle)
    subscriber = subprocess.Popen([sys.executable, str(ROOT / "examples" / "subscribe.py"), "--connect", endpoint, "--vehicle", "bench"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    lead = 3.0
    sender = subprocess.Popen([sys.executable, "-m", "fuser.cli", "sim", "--scenario", "full", "--duration", str(seconds),
                               "--imu-rate", str(imu_hz), "--send", f"udpout:127.0.0.1:{udp}", "--start-at", f"{time.time() + lead:.6f}"],
                              cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rec = None if record is None else RecorderProcess(record)
    try:
        if rec is None:
            pipeline = Pipeline(config, [], [pub.publish_estimate])
        else:
            pipeline = Pipeline(config, [rec.write_sample], [rec.write_estimate, pub.publish_estimate])
        runner = LiveRunner(pipeline, {"mavlink": source}, [lambda t, d: pub.publish_status(d)],
                            lambda: {"publisher": {"errors": pub.errors, "subscribed": pub.has_subscribers}})
        status = runner.run(lead + seconds)
        sender.wait(30)
    finally:
        if rec is not None:
            rec.close()
        for p in (sender, subscriber):
            if p.poll() is None:
                p.kill()
            p.wait(10)
        pub.close()
        source.close()
    late = [line for line in (sender.stderr.read() if sender.stderr else "").splitlines() if "late" in line]
    return {"status": status, "sender_late": late}


def fastest_us(run: Callable[[], int], passes: int = PASSES) -> float:
    """Microseconds per item of the fastest of ``passes`` calls of ``run`` (which returns its item count)."""
    best, count = float("inf"), 1
    for _ in range(passes):
        start = time.perf_counter()
        count = run()
        best = min(best, time.perf_counter() - start)
    return best / max(count, 1) * 1e6


@dataclass(frozen=True)
class LogMessages:
    """One log's messages as a replay meets them: stored JSON, decoded samples, the same samples as MAVLink."""

    name: str
    raw: list[RawMessage]
    inputs: list[tuple[Sample, int]]
    estimates: list[Estimate]
    packets: list[bytes]
    """Each MAVLink-encodable input as one MAVLink 2 packet (HIGHRES_IMU, ATTITUDE_QUATERNION, GPS_RAW_INT)."""


def log_messages(log: Path, system: int) -> LogMessages:
    """``system`` is the MAVLink sender id of the log's packets, one per log, so each log is its own stream."""
    contents = read_log(log)
    inputs = contents.inputs()
    encoder = MavlinkEncoder(system=system)
    packets = [encoder.encode(s) for s, _ in inputs if isinstance(s, (ImuSample, AttitudeSample, GnssSample))]
    return LogMessages(log.name, contents.raw, inputs, contents.estimates(), packets)


def parse_floor_us(packets: list[bytes]) -> float:
    """Bare pymavlink: ``parse_buffer`` of each packet (the decode floor), microseconds per packet."""
    def run() -> int:
        parser = dialect_module("common").MAVLink(None)
        parser.robust_parsing = True
        return sum(len(parser.parse_buffer(p) or ()) for p in packets)

    return fastest_us(run)


def decoder_feed_us(packets: list[bytes]) -> float:
    def run() -> int:
        decoder = MavlinkDecoder()
        return sum(len(decoder.feed(p)) for p in packets)

    return fastest_us(run)


def vqf_seconds(inputs: list[tuple[Sample, int]]) -> float | None:
    """VQF's 9-D filter (6-D where the IMU has no magnetometer) on the IMU samples of one log: seconds
    of the fastest pass, or None when vqf is not installed."""
    try:
        from vqf import VQF
    except ImportError:
        return None
    imu = [s for s, _ in inputs if isinstance(s, ImuSample)]
    gyr = np.ascontiguousarray([s.gyro_rad_s for s in imu], dtype=float)
    acc = np.ascontiguousarray([s.accel_m_s2 for s in imu], dtype=float)
    mag = np.ascontiguousarray([s.mag_gauss for s in imu], dtype=float) if all(s.mag_gauss for s in imu) else None
    ts = float(np.median(np.diff([s.t_ns for s in imu]))) * 1e-9

    def run() -> int:
        VQF(ts).updateBatch(gyr, acc, mag)
        return 1

    return fastest_us(run) * 1e-6


def message_costs(logs: list[LogMessages], tmp_dir: Path) -> list[tuple[str, str, str, str]]:
    """Rows of the table: the cost of each step per message, over all logs, beside the decode floor."""
    packets = [p for lm in logs for p in lm.packets]
    inputs = [i for lm in logs for i in lm.inputs]
    estimates = [e for lm in logs for e in lm.estimates]
    raw = [m for lm in logs for m in lm.raw]
    stored_inputs = [m for lm in logs for m in lm.raw if m.topic in INPUT_TOPICS]
    floor = parse_floor_us(packets)
    out = tmp_dir / "write.mcap"

    def encode_samples() -> int:
        for s, r in inputs:
            sample_json(s, r)
        return len(inputs)

    def encode_estimates() -> int:
        for e in estimates:
            e.to_json()
        return len(estimates)

    def encode_poses() -> int:
        for e in estimates:
            dumps(pose_in_frame(e.t_ns, e.q_wxyz))
        return len(estimates)

    def write_messages() -> int:
        with McapRecorder(out) as rec:
            for m in raw:
                rec.write_message(*m)
        return len(raw)

    def read_logs() -> int:
        return read_log(out).records

    def decode_inputs() -> int:
        for m in stored_inputs:
            decode_sample(m.topic, loads(m.data))
        return len(stored_inputs)

    costs = [
        (f"MavlinkDecoder.feed, one packet a call ({len(packets):,} packets)", decoder_feed_us(packets)),
        (f"sample_json, as the recorder encodes a sample ({len(inputs):,} samples)", fastest_us(encode_samples)),
        (f"Estimate.to_json() ({len(estimates):,} estimates)", fastest_us(encode_estimates)),
        ("dumps(pose_in_frame(...)), an estimate's /pose", fastest_us(encode_poses)),
        (f"McapRecorder.write_message ({len(raw):,} messages, zstd chunks, close)", fastest_us(write_messages)),
        ("read_log of those messages (chunks, CRCs, headers)", fastest_us(read_logs)),
        (f"loads + decode_sample, as replay decodes ({len(stored_inputs):,} stored inputs)", fastest_us(decode_inputs)),
    ]
    rows = [(f"per message: pymavlink parse_buffer, the decode floor ({len(packets):,} packets)", f"{floor:.2f} us", "", "1.00x floor")]
    rows += [(f"per message: {name}", f"{us:.2f} us", "", f"{us / floor:.2f}x floor") for name, us in costs]
    peer = [vqf_seconds(lm.inputs) for lm in logs]
    imu = sum(isinstance(s, ImuSample) for s, _ in inputs)
    if None in peer:
        rows.append(("per IMU sample: VQF", VQF_MISSING, "", ""))
    else:
        vqf = sum(peer) / imu * 1e6  # type: ignore[arg-type]
        rows.append((f"per IMU sample: VQF updateBatch, the same samples ({imu:,})", f"{vqf:.2f} us", "", f"{vqf / floor:.2f}x floor"))
    return rows


def replay_rows(logs: list[Path], messages: dict[Path, LogMessages], tmp_dir: Path, sim: Path, sim_seconds: float,
                baseline: tuple[str, Path] | None) -> tuple[list, dict]:
    """Per log: replay throughput and the model's cost per tick against the targets, beside the decode floor on its
    bytes and VQF on its samples; with a baseline (revision, its worktree), that code's figures measured just before
    and just after this tree's on the same log (the fastest of both), so both see the same load."""
    rows, results = [], {}
    for log in logs:
        first = None if baseline is None else bench_baseline(baseline[1], log)
        r = results[log] = bench_replay(log, tmp_dir / "out.mcap")
        if baseline is not None:
            second = bench_baseline(baseline[1], log)
            before = {"imu_per_s": max(first["imu_per_s"], second["imu_per_s"]), "tick_us": min(first["tick_us"], second["tick_us"])}
        lm = messages[log]
        name = log.name if log != sim else f"simulated 400 Hz, {sim_seconds:g} s"
        rows.append((f"replay {name}", f"{r['imu_per_s']:,.0f} IMU samples/s ({r['imu']:,} in {r['seconds']:.2f} s)",
                     f">= {REPLAY_TARGET:,.0f}/s", f"{r['imu_per_s'] / REPLAY_TARGET:.2f}x target"))
        rows.append(("  model per tick (bench_tick: model + wire estimate)", f"{r['tick_us']:.1f} us", f"<= {TICK_TARGET_US:g} us",
                     f"{r['tick_us'] / TICK_TARGET_US:.2f}x target"))
        if baseline is not None:
            ref = baseline[0]
            rows.append((f"  replay with {ref}'s code, same run", f"{before['imu_per_s']:,.0f} IMU samples/s", "this / baseline",
                         f"{r['imu_per_s'] / before['imu_per_s']:.2f}x"))
            rows.append((f"  model per tick with {ref}'s code, same run", f"{before['tick_us']:.1f} us", "baseline / this",
                         f"{before['tick_us'] / r['tick_us']:.2f}x"))
        floor = 1e6 / parse_floor_us(lm.packets)
        rows.append(("  decode floor: parse_buffer on its inputs as MAVLink", f"{floor:,.0f} packets/s", "replay / floor",
                     f"{r['samples'] / r['seconds'] / floor:.3f}x"))
        vqf = vqf_seconds(lm.inputs)
        if vqf is None:
            rows.append(("  VQF on its IMU samples", VQF_MISSING, "", ""))
        else:
            rows.append(("  VQF on its IMU samples", f"{r['imu'] / vqf:,.0f} IMU samples/s", "replay / VQF", f"{vqf / r['seconds']:.4f}x"))
    return rows, results


def live_rows(seconds: float, record: Path | None, loop_hz: float) -> list[tuple[str, str, str, str]]:
    live = bench_live(seconds, 400.0, record, loop_hz)
    st = live["status"]
    lat = st["latency"]
    recording = ", recording" if record is not None else ""
    target_ms = LATENCY_P99_TARGET_MS.get(loop_hz)
    rows = [
        (f"live latency p50 ({st['estimates']} estimates, 400 Hz UDP in, {loop_hz:g} Hz loop{recording})", f"{lat['p50_ms']:.3f} ms", "", ""),
        ("live latency p99", f"{lat['p99_ms']:.3f} ms", "" if target_ms is None else f"< {target_ms:g} ms",
         "" if target_ms is None else f"{lat['p99_ms'] / target_ms:.2f}x of budget"),
        ("live latency max", f"{lat['max_ms']:.3f} ms", "", ""),
        ("live overruns", f"{st['runner'].get('overruns', 0)} of {st['estimates']} estimates", "0", ""),
        ("live loop counters", str(st["loop"]), "", ""),
    ]
    if live["sender_late"]:
        rows.append(("sender", "; ".join(live["sender_late"]), "", ""))
    return rows


def print_table(rows: list[tuple[str, str, str, str]]) -> None:
    head = ("measure", "result", "against", "ratio")
    widths = [max(len(r[i]) for r in rows + [head]) for i in range(4)]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    print(line(head))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print(line(r))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", action="store_true", help="cProfile one replay and print where the time goes")
    parser.add_argument("--live-seconds", type=float, default=20.0, help="length of the live run (default: 20)")
    parser.add_argument("--sim-seconds", type=float, default=30.0, help="length of the 400 Hz simulated flight replayed (default: 30)")
    parser.add_argument("--live-loop-hz", type=float, nargs="+", default=[100.0, 400.0],
                        help="the live runs' loop rates (default: 100 and 400, the issue's two latency targets)")
    parser.add_argument("--skip-live", action="store_true")
    parser.add_argument("--skip-replay", action="store_true")
    parser.add_argument("--skip-messages", action="store_true", help="skip the per-message costs")
    parser.add_argument("--record", action="store_true", help="live run records to MCAP too, as `run --record` does")
    parser.add_argument("--ticks-only", action="store_true",
                        help="replay with one estimate per tick ([fuser.extrapolation] every_imu_sample = false), as a fleet replay may")
    parser.add_argument("--baseline", metavar="REF", help="also replay every log with the code of git revision REF, in the same run")
    parser.add_argument("--replay-json", nargs="+", type=Path, help=argparse.SUPPRESS)  # a --baseline child: these logs, as JSON
    args = parser.parse_args()
    if args.ticks_only:
        os.environ[TICKS_ONLY_ENV] = "1"
    if args.replay_json:
        with tempfile.TemporaryDirectory() as tmp:
            print(json.dumps({str(log): bench_replay(log, Path(tmp) / "out.mcap") for log in args.replay_json}))
        return 0

    rows: list[tuple[str, str, str, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        sim = tmp_dir / "sim_400hz.mcap"
        sim_log(sim, args.sim_seconds, 400.0)
        logs = sorted((ROOT / "logs").glob("*.mcap")) + [sim]
        messages = {log: log_messages(log, system) for system, log in enumerate(logs, start=1)}
        results: dict = {}
        if not args.skip_replay:
            if args.baseline is None:
                replayed, results = replay_rows(logs, messages, tmp_dir, sim, args.sim_seconds, None)
            else:
                with baseline_tree(args.baseline) as tree:
                    replayed, results = replay_rows(logs, messages, tmp_dir, sim, args.sim_seconds, (args.baseline, tree))
            rows += replayed
        if not args.skip_live:
            for loop_hz in args.live_loop_hz:
                rows += live_rows(args.live_seconds, tmp_dir / "live.mcap" if args.record else None, loop_hz)
        if not args.skip_messages:
            rows += message_costs(list(messages.values()), tmp_dir)
        print_table(rows)
        if args.profile or (results and min(r["imu_per_s"] for r in results.values()) < REPLAY_TARGET):
            print("\nreplay below target: cProfile of the simulated 400 Hz replay\n")
            print(profile_replay(sim, tmp_dir / "prof.mcap"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
