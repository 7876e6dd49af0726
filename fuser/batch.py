"""Batch replay: many logs, one task each, in local processes or on a Dask cluster.

    bingham-fuser replay a.tlog b.mcap c.mcap --out-dir DIR --jobs 2
    bingham-fuser replay archive/*.mcap --out-dir /shared/fused --dask tcp://scheduler:8786

Each log is replayed by :func:`fuser.replay.replay` exactly as a single
``replay LOG -o OUT`` would, into ``DIR/<log stem>.mcap``, so the files do not
depend on where a task ran: ``--jobs 1``, ``--jobs N`` and a Dask cluster
write the same bytes. Local workers are started with the ``spawn`` method
(the parent may run zenoh threads, which must never be forked). A log that
fails is a row of the summary with its reason, never the end of the batch;
the exit status says whether any failed. On Dask, every path must name the
same file on the workers as here (a shared filesystem), and the workers need
the same version of bingham-fuser installed.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterable, Sequence, TextIO

from fuser import argtypes
from fuser.config import FuserConfig
from fuser.errors import log_file_problem

__all__ = ["LogResult", "LogTask", "add_replay_arguments", "command", "format_summary", "is_batch", "output_paths",
           "run_batch", "run_task"]

SCORE_SINCE_S = 5.0
"""The error against the reference leaves out this much convergence at the start (as ``report`` does)."""
REJECTION_COUNTERS = ("late", "gated")
"""Loop and model counters whose name holds one of these count a refused sample or measurement."""
COMPILE_SHOWN_S = 0.05
"""A replay that compiled the filter for this long (s; one decimal shows it) says so beside its rate, which leaves
the compiling out (``replay LOG -o OUT``'s line, a batch's notes)."""
CLUSTER_EXTRA = "pip install 'bingham-fuser[cluster]'"
DASK_CONNECT_TIMEOUT_S = 10.0
"""How long to try reaching the Dask scheduler before giving up."""


class BatchError(Exception):
    """A batch that cannot start (bad arguments, no Dask, no scheduler): one line for the user."""


@dataclass(frozen=True)
class LogTask:
    """One log to replay into ``output`` with ``config``."""

    log: str
    output: str
    config: FuserConfig


@dataclass(frozen=True)
class LogResult:
    """What one task did. ``reason`` (one line) is empty when ``ok``; a failed task's output file is removed."""

    log: str
    output: str
    ok: bool
    reason: str = ""
    samples: int = 0
    """Input samples fed to the loop."""
    estimates: int = 0
    seconds: float = 0.0
    """The replay's own wall time (reading, fusing, writing), without the scoring."""
    compile_seconds: float = 0.0
    """Of ``seconds``, those its worker spent compiling the filter (its first log after installing)."""
    accepted: int = 0
    """Samples the loop buffered for a tick (the others came late)."""
    rejected: int = 0
    """Late samples and gated measurements (``REJECTION_COUNTERS``), the column "late+gated": not the samples a
    decoder refused (``input_refused``, a single ``replay``'s "not used")."""
    error_deg: float | None = None
    """RMS total error against ``reference`` after the first ``SCORE_SINCE_S`` seconds (all of a shorter log)."""
    reference: str | None = None
    inside_90: float | None = None
    """The share of those estimates whose 90 % credible region held the reference (calibrated: about 0.9)."""
    not_imported: dict[str, int] = field(default_factory=dict)
    """For a log replayed through ``import`` (DataFlash, ULog, BROAD): what the import left out, by reason."""
    input_warning: str | None = None
    """For a .tlog: the warning ``replay LOG`` prints when little of its IMU data reached the loop
    (:meth:`fuser.inputs.InputReport.warning`), else None."""
    input_refused: dict[str, int] = field(default_factory=dict)
    """For a .tlog with ``input_warning``: what was not used, by reason (:attr:`fuser.inputs.InputReport.refused`)."""

    @property
    def samples_per_s(self) -> float:
        """The replay's rate, without the compiling."""
        fusing = self.seconds - self.compile_seconds
        return self.samples / fusing if fusing > 0 else 0.0


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _failed(task: LogTask, reason: str) -> LogResult:
    Path(task.output).unlink(missing_ok=True)
    return LogResult(task.log, task.output, False, reason)


def _score(output: str) -> tuple[float | None, str | None, float | None]:
    """The RMS total error of ``output``'s estimates, its reference's name, as ``report`` names it (simulator
    truth, motion capture, EKF2, ...: an autopilot's estimate is not called truth), marked ``(circular)`` where the
    fuser fused that autopilot's attitude (``replay`` prints why), and the share of the estimates whose 90 % credible
    region held it. The output is read as a stream (:func:`fuser.report.stream_score`), so scoring a long log takes no
    more memory than a short one."""
    from fuser.report import stream_score

    score = stream_score(output, SCORE_SINCE_S)
    if score.unscored is not None or score.matched == 0:  # no reference, or none within the estimates' time span
        return None, None, None
    return score.rms["total"], score.reference.name + (" (circular)" if score.circular else ""), score.coverage.get(0.9)


def run_task(task: LogTask, notice: Callable[[], None] | None = None) -> LogResult:
    """Replay one log and score it; any error becomes a failed result (this runs in a worker, or in the batch's
    process with ``notice``, :func:`fuser.replay.replay`'s)."""
    from fuser.replay import replay

    problem = log_file_problem(task.log)
    if problem is not None:
        return _failed(task, problem)
    try:
        summary = replay(task.log, task.output, task.config, progress=None, notice=notice)  # a log with nothing to fuse raises
        error_deg, reference, inside_90 = _score(task.output)
    except Exception as exc:  # noqa: BLE001 - one log's failure is a row of the summary, not the end of the batch
        return _failed(task, _one_line(exc))
    counters = summary.counters
    rejected = sum(v for k, v in counters.items() if any(mark in k for mark in REJECTION_COUNTERS))
    warning = None if summary.inputs is None else summary.inputs.warning()
    return LogResult(task.log, task.output, True, samples=summary.samples, estimates=summary.estimates, seconds=summary.seconds,
                     compile_seconds=summary.compile_seconds, accepted=counters.get("samples", 0), rejected=rejected,
                     error_deg=error_deg, reference=reference, inside_90=inside_90, not_imported=dict(summary.imported or {}), input_warning=warning,
                     input_refused=summary.inputs.refused if warning is not None else {})  # type: ignore[union-attr]


def output_paths(logs: Sequence[str | Path], out_dir: str | Path) -> list[Path]:
    """``out_dir/<stem>.mcap`` per log, in argument order; a name already taken (case-insensitively, as on
    some filesystems) becomes ``<stem>-2``, ``<stem>-3``, ...: the same arguments always give the same names."""
    taken: set[str] = set()
    out = []
    for log in logs:
        stem = Path(log).stem
        name, k = stem, 2
        while name.casefold() in taken:
            name, k = f"{stem}-{k}", k + 1
        taken.add(name.casefold())
        out.append(Path(out_dir) / f"{name}.mcap")
    return out


def _tasks(logs: Sequence[str | Path], out_dir: str | Path, config: FuserConfig) -> list[LogTask]:
    outputs = output_paths(logs, out_dir)
    inputs = {Path(log).resolve() for log in logs}
    for out in outputs:
        if out.resolve() in inputs:
            raise BatchError(f"the output {out} would overwrite an input log: choose another --out-dir")
    return [LogTask(str(log), str(out), config) for log, out in zip(logs, outputs)]


def _largest_first(tasks: Sequence[LogTask]) -> list[LogTask]:
    """Longest jobs first, so the last ones to finish are short (the batch's tail); missing files last."""
    def size(task: LogTask) -> int:
        try:
            return os.path.getsize(task.log)
        except OSError:
            return -1

    return sorted(tasks, key=size, reverse=True)


def _remove_leftovers(task: LogTask) -> None:
    """The partial output and temporary import a worker killed while replaying ``task`` left behind."""
    from fuser.replay import leftovers

    for path in leftovers(task.log, task.output):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Stop every worker of a broken pool before it is shut down. A worker killed while the pool was starting the
    second hung a batch: the pool's clean-up joined a worker forever, and the shutdown waited for it. The likely
    cause, from CPython 3.11's ``concurrent/futures/process.py``: a worker that a submit spawns while the pool is
    breaking is added to the pool's record of its workers only once started, after the clean-up has terminated
    the others. The record, ``_processes``, is private, but it is the only handle on the workers the pool holds."""
    workers = getattr(pool, "_processes", None) or {}
    for process in list(workers.values()):
        process.kill()


def _in_processes(tasks: Sequence[LogTask], jobs: int, done: Callable[[LogResult], None]) -> None:
    """Local worker processes (spawned). A worker that dies (killed, out of memory) breaks the whole pool,
    so each task it took down is run again alone in a fresh process: only a log that kills its own
    process fails. A worker can die while the pool is still starting the others: the tasks not yet
    submitted then go the same way."""
    spawn = mp.get_context("spawn")
    broken: list[LogTask] = []
    with ProcessPoolExecutor(max_workers=jobs, mp_context=spawn) as pool:
        futures = {}
        for task in _largest_first(tasks):
            try:
                futures[pool.submit(run_task, task)] = task
            except (BrokenProcessPool, OSError, ValueError):  # broken already, or while spawning a worker: "handle is closed",
                broken.append(task)  # or "bad value(s) in fds_to_keep" (the dead worker's pipe closed under the spawn)
        for future in as_completed(futures):
            try:
                done(future.result())
            except BrokenProcessPool:
                broken.append(futures[future])
        if broken:
            _stop_workers(pool)
    for task in broken:
        _remove_leftovers(task)  # of the worker that died with it
        with ProcessPoolExecutor(max_workers=1, mp_context=spawn) as alone:
            try:
                done(alone.submit(run_task, task).result())
            except BrokenProcessPool:
                _remove_leftovers(task)
                done(_failed(task, "the worker process died (killed, or out of memory)"))


def _on_dask(tasks: Sequence[LogTask], address: str, done: Callable[[LogResult], None]) -> None:
    """One Dask task per log on the cluster whose scheduler is at ``address``."""
    try:
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_completed
    except ImportError:
        raise BatchError(f"--dask needs dask.distributed: {CLUSTER_EXTRA}") from None
    try:
        client = Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler at {address}: {_one_line(exc)}") from None
    with client:
        futures = {client.submit(run_task, t, pure=False): t for t in _largest_first(tasks)}
        for future in dask_completed(list(futures)):
            task = futures[future]
            try:
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - a worker lost or a task refused by the cluster
                result = _failed(task, _one_line(exc))
            if result.ok and not Path(result.output).exists():
                result = replace(result, ok=False, reason="the worker wrote its output where this machine cannot see it "
                                                          "(is --out-dir on a filesystem the workers share?)")
            done(result)


def run_batch(
    logs: Sequence[str | Path],
    out_dir: str | Path,
    config: FuserConfig,
    jobs: int = 1,
    dask_address: str | None = None,
    progress: TextIO | None = None,
    notice: Callable[[], None] | None = None,
) -> list[LogResult]:
    """Replay every log into ``out_dir`` (created), with ``jobs`` local processes (1: in this process)
    or on the Dask cluster at ``dask_address``; results in the order of ``logs``.

    ``progress``: a stream for one progress bar over all logs, shown only if it is a terminal. ``notice``: called
    once if the filter's kernels have been compiling for :data:`fuser.compiling.NOTICE_AFTER_S` (the first run after
    installing). Before local worker processes start, the kernels are compiled here (:func:`fuser.warmup.warm_up`),
    once, and every worker loads them from numba's cache: otherwise each worker compiled the same kernels side by
    side without a word (three logs, ``--jobs 2``, an empty cache: 30 s of wall, 54 s of CPU) and wrote the same
    cache entries at once. Dask workers compile their own (they may be other machines, with their own caches).
    """
    if jobs < 1:
        raise BatchError(f"--jobs must be at least 1, got {jobs}")
    tasks = _tasks(logs, out_dir, config)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    in_processes = dask_address is None and jobs > 1 and len(tasks) > 1
    if in_processes:
        from fuser.warmup import warm_up

        warm_up(config, notice)
    results: dict[str, LogResult] = {}
    bar = _bar(len(tasks), progress)

    def done(result: LogResult) -> None:
        results[result.output] = result
        bar.update(1)
        bar.set_postfix(failed=sum(not r.ok for r in results.values()), refresh=False)

    try:
        if dask_address is not None:
            _on_dask(tasks, dask_address, done)
        elif in_processes:
            _in_processes(tasks, min(jobs, len(tasks)), done)
        else:
            for task in tasks:
                done(run_task(task, notice))
    finally:
        bar.close()
    return [results[t.output] for t in tasks]


def _bar(total: int, stream: TextIO | None):
    from tqdm import tqdm

    return tqdm(total=total, unit="log", desc="replay", file=stream, disable=stream is None or not stream.isatty())


def _listed(counts: dict[str, int]) -> str:
    """``reason=count, ...`` in the order given."""
    return ", ".join(f"{k}={v:,}" for k, v in counts.items())


def format_summary(results: Iterable[LogResult], wall_s: float | None = None) -> list[str]:
    """The summary table, one row per log, and a closing line with the totals."""
    results = list(results)
    head = ("log", "status", "samples", "estimates", "seconds", "samples/s", "accepted", "late+gated", "in 90 % region",
            "error (deg RMS)")
    rows = []
    for r in results:
        if r.ok:
            error = "-" if r.error_deg is None else f"{r.error_deg:.2f} vs {r.reference}"
            inside = "-" if r.inside_90 is None else f"{100 * r.inside_90:.0f} %"
            rows.append((r.log, "ok", f"{r.samples:,}", f"{r.estimates:,}", f"{r.seconds:.2f}", f"{r.samples_per_s:,.0f}",
                         f"{r.accepted:,}", f"{r.rejected:,}", inside, error))
        else:
            rows.append((r.log, "failed", "", "", "", "", "", "", "", r.reason))
    widths = [max(len(row[i]) for row in [head, *rows]) for i in range(len(head) - 1)]
    numeric = range(2, 9)

    def line(row: tuple[str, ...]) -> str:
        cells = [c.rjust(w) if i in numeric else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))]
        return "  ".join(cells + [row[-1]]).rstrip()

    notes = [f"{r.log}: not imported: {_listed(r.not_imported)}"
             + (" (the log was cut short, or ends in garbage)" if "incomplete_tail_bytes" in r.not_imported else "")
             for r in results if r.not_imported]
    notes += [f"{r.input_warning} (not used: {_listed(r.input_refused)})"
              for r in results if r.input_warning]
    compiled = sum(r.compile_seconds for r in results)
    if compiled >= COMPILE_SHOWN_S:
        notes.append(f"samples/s leave out the {compiled:.1f} s spent compiling the filter (the first logs after installing)")
    failed = sum(not r.ok for r in results)
    samples = sum(r.samples for r in results)
    total = f"replay: {len(results)} logs, {len(results) - failed} ok, {failed} failed; {samples:,} samples"
    if wall_s is not None:
        total += f" in {wall_s:.1f} s ({samples / wall_s if wall_s > 0 else 0.0:,.0f} samples/s)"
    return [line(head), *(line(row) for row in rows), *notes, total]


def _cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def add_replay_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``replay`` subcommand's own arguments: one log with ``-o``, or many with ``--out-dir``."""
    parser.add_argument("log", nargs="+", help="input logs (.mcap recorded by bingham-fuser, MAVLink .tlog, or a log import reads: "
                                                "DataFlash .bin, PX4 .ulg, BROAD .hdf5)")
    parser.add_argument("-o", "--output", metavar="OUT.mcap", help="where to write the replayed estimates of one log")
    g = parser.add_argument_group("many logs", "replay each log into DIR/<log stem>.mcap, in parallel, with a summary "
                                  "table; the exit status is 1 if any log failed")
    g.add_argument("--out-dir", metavar="DIR", help="folder for the replayed logs (created)")
    where = g.add_mutually_exclusive_group()
    where.add_argument("--jobs", type=argtypes.integer(1), metavar="N", help="local worker processes (default: the cores available)")
    where.add_argument("--dask", metavar="SCHEDULER_ADDRESS", help="run each log as a task on this Dask cluster, e.g. "
                       f"tcp://host:8786; paths must be the same on the workers ({CLUSTER_EXTRA})")


def is_batch(args: argparse.Namespace) -> bool:
    """Whether the ``replay`` arguments ask for a batch (anything but one log with ``-o``)."""
    return args.output is None or len(args.log) > 1 or args.out_dir is not None or args.jobs is not None or args.dask is not None


def command(args: argparse.Namespace, config: FuserConfig, notice: Callable[[], None] | None = None) -> int:
    """``bingham-fuser replay LOG... --out-dir DIR [--jobs N | --dask ADDRESS]``; ``notice`` as :func:`run_batch`'s."""
    if args.output is not None:
        what = "several logs" if len(args.log) > 1 else "--out-dir, --jobs and --dask"
        print(f"replay: -o is for one log; {what} need --out-dir DIR instead", file=sys.stderr)
        return 2
    if args.out_dir is None:
        print("replay: give -o OUT.mcap for one log, or --out-dir DIR", file=sys.stderr)
        return 2
    start = time.monotonic()
    try:
        results = run_batch(args.log, args.out_dir, config, args.jobs or _cores(), args.dask, progress=sys.stderr, notice=notice)
    except BatchError as exc:
        print(f"replay: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("replay: interrupted; the logs not finished have no output", file=sys.stderr)
        return 130
    for line in format_summary(results, time.monotonic() - start):
        print(line)
    return 0 if all(r.ok for r in results) else 1
