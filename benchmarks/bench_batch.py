"""Batch replay throughput: --jobs 2 (and a two-worker local Dask cluster) against --jobs 1.

    python benchmarks/bench_batch.py              # 12 copies of every log in logs/, twice (about five minutes)
    python benchmarks/bench_batch.py --copies 2   # quicker, with more start-up in the ratio

Every process pays a fixed start-up before its first log (a spawned worker about 1.5 s of
imports, then every process about 1.2 s for numba's cache and the first call of the model),
which a fleet's archive amortises over many logs and a handful does not: with one copy of
each log (6 logs, 6 s of work) --jobs 2 is only about 1.4 times as fast.

Each run is the command a user types, ``bingham-fuser replay LOG... --out-dir DIR --jobs N``
(or ``--dask`` to a two-worker local cluster started here), in a new process, timed from
its start to its exit: process start-up (the parent's, and the spawned workers' imports of
numpy, scipy, numba's cache and the model) is part of the cost. The ratio is the --jobs 1
wall time over the other's (fastest of two alternating runs each); the target is 1.8 on a
two-core machine. The outputs of every
run are checked to be byte-identical to --jobs 1's. The load average before and after each
run is printed, and the cores the rest of the machine kept busy meanwhile (/proc/stat's busy
time less the run's own CPU; for the Dask run the workers are not this run's children, so it
counts them too): on a shared machine a loaded run understates the ratio. Beside it, the
machine's own ceiling, measured between the runs: two processes of pure arithmetic against one.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fuser.batch import output_paths  # noqa: E402
from fuser.record import INPUT_TOPICS, read_log  # noqa: E402

TARGET = 1.8
CEILING_WORK = "s = 0\nfor i in range(40_000_000):\n    s += i * i\n"
"""About 3 s of pure-Python arithmetic: no I/O, no memory traffic, nothing shared."""


def copies(logs: list[Path], n: int, folder: Path) -> list[Path]:
    """``n`` links to each log, under distinct stems, so the outputs need no collision suffix."""
    folder.mkdir()
    out = []
    for k in range(n):
        for log in logs:
            link = folder / f"{log.stem}_{k}{log.suffix}"
            link.symlink_to(log)
            out.append(link)
    return out


def load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def busy_cpu_s() -> float:
    """CPU seconds the whole machine has spent busy since boot (/proc/stat: all but idle and iowait)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def timed_replay(inputs: list[Path], out_dir: Path, where: list[str]) -> tuple[float, str, str]:
    """Wall seconds of one ``bingham-fuser replay ... --out-dir`` process, the load around it, and the CPU
    the rest of the machine used meanwhile (busy CPU minus this run's own, as cores)."""
    before, busy, own = load(), busy_cpu_s(), resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "fuser.cli", "replay", *map(str, inputs), "--out-dir", str(out_dir), *where],
                         cwd=ROOT, capture_output=True, text=True)
    wall_s = time.perf_counter() - start
    if run.returncode != 0:
        raise SystemExit(f"replay {' '.join(where)} failed ({run.returncode}):\n{run.stdout}{run.stderr}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    own_s = after.ru_utime + after.ru_stime - own.ru_utime - own.ru_stime
    others = (busy_cpu_s() - busy - own_s) / wall_s
    return wall_s, f"{before} -> {load()}", f"{max(others, 0.0):.2f}"


def ceiling() -> tuple[float, str]:
    """The machine's own parallel ceiling: N copies of CEILING_WORK in N processes, N = 1 then 2.
    On virtual cores (KVM here) two busy cores may run slower than one: no batch can beat this."""
    def wall(n: int) -> float:
        start = time.perf_counter()
        procs = [subprocess.Popen([sys.executable, "-c", CEILING_WORK]) for _ in range(n)]
        for proc in procs:
            proc.wait()
        return time.perf_counter() - start

    busy = busy_cpu_s()
    start = time.perf_counter()
    one, two = wall(1), wall(2)
    others = (busy_cpu_s() - busy - 3 * one) / (time.perf_counter() - start)  # our own: 3 copies of about `one` each
    return 2 * one / two, f"{max(others, 0.0):.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=12, help="copies of each log in logs/ (default: 12)")
    parser.add_argument("--repeats", type=int, default=2, help="alternating runs of --jobs 1 and 2, fastest counts (default: 2)")
    parser.add_argument("--no-dask", action="store_true", help="skip the local Dask cluster")
    args = parser.parse_args()

    logs = sorted((ROOT / "logs").glob("*.mcap"))
    samples = args.copies * sum(len(read_log(log).of(INPUT_TOPICS)) for log in logs)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        inputs = copies(logs, args.copies, tmp_dir / "in")
        runs: dict[str, tuple[float, str, str]] = {}
        ceilings = []
        for _ in range(args.repeats):
            ceilings.append(ceiling())  # alternating, so that a burst of other work hits one run of each, not all
            for name, folder, where in (("--jobs 1", "jobs1", ["--jobs", "1"]), ("--jobs 2", "jobs2", ["--jobs", "2"])):
                run = timed_replay(inputs, tmp_dir / folder, where)
                runs[name] = min(runs.get(name, run), run)
        if not args.no_dask:
            from dask.distributed import LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                runs["--dask, LocalCluster of 2 processes"] = timed_replay(inputs, tmp_dir / "dask", ["--dask", cluster.scheduler_address])
        single_s = runs["--jobs 1"][0]
        for (name, (wall_s, loads, others)), folder in zip(runs.items(), ("jobs1", "jobs2", "dask")):
            same = all(a.read_bytes() == b.read_bytes()
                       for a, b in zip(output_paths(inputs, tmp_dir / "jobs1"), output_paths(inputs, tmp_dir / folder)))
            ratio = single_s / wall_s
            rows.append((name, f"{wall_s:.1f} s", f"{samples / wall_s:,.0f}", f"{ratio:.2f}x",
                         "" if name == "--jobs 1" else ("met" if ratio >= TARGET else "NOT met"), "yes" if same else "NO", loads, others))

    print(f"{len(inputs)} logs ({args.copies} copies of the {len(logs)} in logs/), {samples:,} input samples; "
          f"{os.cpu_count()} cores; target: {TARGET}x the single-process throughput")
    best, others = max(ceilings)
    print(f"machine ceiling (2 processes of pure-Python arithmetic against 1, best of {len(ceilings)}): {best:.2f}x, "
          f"with {others} cores used by others; the --jobs 2 ratio is {runs['--jobs 1'][0] / runs['--jobs 2'][0] / best:.0%} of it")
    head = ("run", "wall", "samples/s", "ratio to --jobs 1", f">= {TARGET}x", "bytes = --jobs 1", "load 1/5/15 min before -> after",
            "cores used by others")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    print(line(head))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print(line(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
