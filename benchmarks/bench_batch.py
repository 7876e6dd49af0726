"""Batch replay throughput: --jobs 2 (and a two-worker local Dask cluster) against --jobs 1.

    python benchmarks/bench_batch.py              # 6 copies of every log in logs/ (about two minutes)
    python benchmarks/bench_batch.py --copies 2   # quicker, with more start-up in the ratio

Each run is ``fuser.batch.run_batch`` over the same logs into a fresh folder, timed from
the call to the last summary row: process start-up (spawned workers import numpy, numba's
cache, the model) is part of the cost. The ratio is the single-process wall time over the
parallel one; the target is 1.8 on a two-core machine. The outputs of every run are checked
to be byte-identical to --jobs 1's. The load average before and after each run is printed:
on a shared machine a loaded run understates the ratio.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fuser.batch import LogResult, run_batch  # noqa: E402
from fuser.config import FuserConfig  # noqa: E402

TARGET = 1.8


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


def timed(run: Callable[[], list[LogResult]]) -> tuple[float, list[LogResult], str]:
    before = load()
    start = time.perf_counter()
    results = run()
    return time.perf_counter() - start, results, f"{before} -> {load()}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=6, help="copies of each log in logs/ (default: 6)")
    parser.add_argument("--no-dask", action="store_true", help="skip the local Dask cluster")
    args = parser.parse_args()

    logs = sorted((ROOT / "logs").glob("*.mcap"))
    config = FuserConfig()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp_dir = Path(tmp)
        inputs = copies(logs, args.copies, tmp_dir / "in")
        runs: dict[str, tuple[float, list[LogResult], str]] = {
            "--jobs 1": timed(lambda: run_batch(inputs, tmp_dir / "jobs1", config, jobs=1)),
            "--jobs 2": timed(lambda: run_batch(inputs, tmp_dir / "jobs2", config, jobs=2)),
        }
        if not args.no_dask:
            from dask.distributed import LocalCluster

            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                runs["Dask, LocalCluster of 2 processes"] = timed(
                    lambda: run_batch(inputs, tmp_dir / "dask", config, dask_address=cluster.scheduler_address))
        single_s, single, _ = runs["--jobs 1"]
        assert all(r.ok for r in single), [r.reason for r in single if not r.ok]
        samples = sum(r.samples for r in single)
        for name, (wall_s, results, loads) in runs.items():
            same = all(Path(a.output).read_bytes() == Path(b.output).read_bytes() for a, b in zip(single, results))
            ratio = single_s / wall_s
            rows.append((name, f"{wall_s:.1f} s", f"{samples / wall_s:,.0f}", f"{ratio:.2f}x",
                         "" if name == "--jobs 1" else ("met" if ratio >= TARGET else "NOT met"), "yes" if same else "NO", loads))

    print(f"{len(inputs)} logs ({args.copies} copies of the {len(logs)} in logs/), {samples:,} input samples; "
          f"{os.cpu_count()} cores; target: {TARGET}x the single-process throughput")
    head = ("run", "wall", "samples/s", "ratio to --jobs 1", f">= {TARGET}x", "bytes = --jobs 1", "load 1/5/15 min before -> after")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    print(line(head))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print(line(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
