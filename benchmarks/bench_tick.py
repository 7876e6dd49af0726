"""The fusion model's cost per tick, the compiled tick and the Python around it, on the ticks of every log in logs/.

    python benchmarks/bench_tick.py               # table: us per tick, per log, by part; compile cost cold and warm
    python benchmarks/bench_tick.py --runs 7      # median of 7 runs (default 5)
    python benchmarks/bench_tick.py --skip-compile
    python benchmarks/bench_tick.py --baseline main   # REF's code too, in the same run: per tick and compile cost
    python benchmarks/bench_tick.py --compile-units --baseline main   # where the cold compile goes, per kernel

Each log is replayed once through the loop (:class:`fuser.pipeline.Pipeline`)
to capture the :class:`~fuser.model.tick.TickInput` of every tick; then a
fresh :class:`~fuser.model.FusionModel` steps through those inputs, and the
loop's :func:`~fuser.loop.estimate_of` builds each wire estimate ("publish"),
so the figures are the model's alone, no decoding or recording. The total per
tick is timed bare, the median of ``--runs`` runs. With ``--baseline REF`` the
same totals are measured with REF's code (a temporary worktree, in a child
process) just before and just after this tree's, the fastest of both kept
(this tree's then get as many runs).

The split is measured in a separate run with the compiled tick
(:func:`fuser.model.fusion.tick`, one numba function for the whole tick: its
steps cannot be timed apart from Python) wrapped by a timer; the timer's own
cost per call, calibrated on an empty function, is taken off. The rest of
``FusionModel.step`` (the tick's samples laid out as arrays, the reference
field, the diagnostics and counters turned back into Python values) is "the
Python around it".

Compile cost (numba, ``cache=True``): a new interpreter imports the model and
steps one tick of a simulated flight, once after deleting the on-disk caches
of ``core/`` (cold: every kernel compiled) and once more (warm: loaded from the
cache). Targets (issue 17): 25 us per tick; cold < 10 s, warm < 1 s.
``--compile-units`` splits the cold compile by compile unit (a kernel and
its type signature: a kernel compiled twice shows twice), from numba's
compile events, in CPU seconds (less sensitive to the other jobs than wall
time), each unit less the units compiled inside it.

The machine is shared: figures are noisy; the medians and the fastest runs are
both printed.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Callable, Iterator

ROOT = Path(os.environ.get("BENCH_CODE_ROOT") or Path(__file__).resolve().parent.parent)
"""The tree whose code is measured (``bench_fuser.py --baseline`` sets another revision's)."""
sys.path.insert(0, str(ROOT))

import fuser.model.fusion as fusion  # noqa: E402
from fuser.config import FuserConfig, load_config  # noqa: E402
from fuser.loop import estimate_of  # noqa: E402
from fuser.model import FusionModel, TickInput  # noqa: E402
from fuser.pipeline import Pipeline  # noqa: E402
from fuser.record import read_log  # noqa: E402

TICK_TARGET_US = 25.0
COLD_TARGET_S = 10.0
WARM_TARGET_S = 1.0

# part -> (namespace, attribute) of every function of that part FusionModel.step calls
STEPS: dict[str, list[tuple[object, str]]] = {
    "compiled tick (fuser.model.fusion.tick)": [(fusion, "tick")],
}
PUBLISH = "publish (estimate_of: the wire Estimate)"
OWN = "the Python around it (samples in, diagnostics and counters out)"


def config_for(log: Path) -> FuserConfig:
    """The settings a log is replayed with: the .toml beside it (an imported log's earth field), else the defaults."""
    toml = log.with_suffix(".toml")
    return load_config(toml if toml.exists() else None)


def captured_ticks(log: Path, config: FuserConfig) -> list[TickInput]:
    """The TickInput of every tick of a replay of ``log`` (as :func:`fuser.replay.replay` feeds the loop)."""
    pipeline = Pipeline(config, [], [], max_catch_up_ticks=1000)
    model = pipeline.loop.model
    ticks: list[TickInput] = []
    step = model.step

    def recording(tick: TickInput):
        ticks.append(tick)
        return step(tick)

    model.step = recording  # type: ignore[method-assign]
    for sample, receive_ns in read_log(log).inputs():
        pipeline.feed(sample, receive_ns)
    pipeline.finish()
    return ticks


def run_ticks(config: FuserConfig, ticks: list[TickInput]) -> float:
    """Seconds to step a fresh model through ``ticks`` and build each estimate."""
    model = FusionModel(config)
    start = time.perf_counter()
    for tick in ticks:
        result = model.step(tick)
        estimate_of(tick.t_ns, result, result.counters, None)
    return time.perf_counter() - start


class StepTimer:
    """Exclusive time per step: each wrapped call's time minus that of the wrapped calls inside it."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._nested: list[float] = []

    def wrap(self, step: str, fn: Callable) -> Callable:
        clock, nested = time.perf_counter, self._nested
        seconds, calls = self.seconds, self.calls

        def timed(*args, **kwargs):
            nested.append(0.0)
            start = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = clock() - start
                inner = nested.pop()
                seconds[step] += elapsed - inner
                calls[step] += 1
                if nested:
                    nested[-1] += elapsed

        return timed


def bare_totals_us(config: FuserConfig, ticks: list[TickInput], runs: int) -> list[float]:
    """``runs`` bare totals, us per tick, of stepping through ``ticks`` (kernels loaded first)."""
    run_ticks(config, ticks[: min(200, len(ticks))])  # kernels loaded, caches warm
    return [run_ticks(config, ticks) / len(ticks) * 1e6 for _ in range(runs)]


def tick_totals_us(logs: list[Path], runs: int) -> dict[str, list[float]]:
    """:func:`bare_totals_us` of each log's ticks, by the log's name."""
    totals = {}
    for log in logs:
        config = config_for(log)
        totals[log.name] = bare_totals_us(config, captured_ticks(log, config), runs)
    return totals


def baseline_totals_us(tree: Path, logs: list[Path], runs: int) -> dict[str, list[float]]:
    """:func:`tick_totals_us` with the code of the worktree ``tree`` (another revision), in a child process."""
    out = subprocess.run([sys.executable, __file__, "--runs", str(runs), "--totals-json", *map(str, logs)], cwd=tree, check=True,
                         capture_output=True, text=True, env={**os.environ, "BENCH_CODE_ROOT": str(tree)})
    return json.loads(out.stdout.strip().splitlines()[-1])


def timer_overhead_s(n: int = 200_000) -> float:
    """Seconds a wrapped call costs more than a bare one."""
    def empty() -> None:
        return None

    timed = StepTimer().wrap("x", empty)
    best = []
    for fn in (empty, timed):
        start = time.perf_counter()
        for _ in range(n):
            fn()
        best.append(time.perf_counter() - start)
    return max(0.0, (best[1] - best[0]) / n)


def split_by_step(config: FuserConfig, ticks: list[TickInput], overhead_s: float) -> dict[str, float]:
    """Microseconds per tick of each step (timer cost taken off), step's own code and publish included."""
    timer = StepTimer()
    saved = []
    for step, names in STEPS.items():
        for ns, name in names:
            original = getattr(ns, name)
            saved.append((ns, name, original))
            setattr(ns, name, timer.wrap(step, original))
    try:
        model = FusionModel(config)
        step_total = publish = 0.0
        for tick in ticks:
            t0 = time.perf_counter()
            result = model.step(tick)
            t1 = time.perf_counter()
            estimate_of(tick.t_ns, result, result.counters, None)
            t2 = time.perf_counter()
            step_total += t1 - t0
            publish += t2 - t1
    finally:
        for ns, name, original in saved:
            setattr(ns, name, original)
    n = len(ticks)
    out = {step: 1e6 * (timer.seconds[step] - overhead_s * timer.calls[step]) / n for step in STEPS}
    wrapped = sum(timer.seconds.values())
    out[OWN] = 1e6 * (step_total - wrapped - overhead_s * sum(timer.calls.values())) / n
    out[PUBLISH] = 1e6 * publish / n
    return out


COMPILE_PROBE = """
import time
start = time.perf_counter()
from drivers.sim import SimConfig, simulate
from fuser.config import FuserConfig
from fuser.pipeline import Pipeline
from fuser.simulate import run_sim
flight = simulate(SimConfig(duration_s=0.5, imu_rate_hz=200.0))
imported = time.perf_counter()
pipeline = Pipeline(FuserConfig(), [], [])
run_sim(pipeline, flight, "mavlink", 0, [])
print(imported - start, time.perf_counter() - imported)
"""


UNITS_PROBE = COMPILE_PROBE.replace("pipeline = Pipeline(", """
from numba.core import event

units, stack = {}, []

def short(t):  # Array(float64, 2, 'C', True, aligned=True) -> float64[2d C read-only]
    if hasattr(t, "ndim") and hasattr(t, "mutable"):
        return f"{t.dtype}[{t.ndim}d {t.layout}{'' if t.mutable else ' read-only'}]"
    return str(t)

class Units(event.Listener):  # each compile's CPU seconds, less those of the compiles nested in it
    def on_start(self, ev):
        stack.append([time.process_time(), 0.0])

    def on_end(self, ev):
        begun, nested = stack.pop()
        spent = time.process_time() - begun
        fn = ev.data["dispatcher"].py_func
        key = "numba's own overloads" if fn.__module__.startswith("numba") else f"{fn.__module__}.{fn.__qualname__}({', '.join(map(short, ev.data['args']))})"
        units[key] = units.get(key, 0.0) + spent - nested
        if stack:
            stack[-1][1] += spent

event.register("numba:compile", Units())
pipeline = Pipeline(""", 1).replace("print(imported - start, time.perf_counter() - imported)", "import json; print(json.dumps(units))")


def numba_caches(root: Path = ROOT) -> list[Path]:
    """numba's on-disk caches of the kernels (``core/`` and the model's, ``fuser/``)."""
    return sorted(p for d in ("core", "fuser") for p in (root / d).rglob("*.nb[ic]"))


@contextmanager
def baseline_tree(ref: str) -> Iterator[Path]:
    """A temporary detached git worktree of revision ``ref`` (outside this tree), removed after."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), ref], check=True, capture_output=True)
        try:
            yield tree
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=True, capture_output=True)


def compile_seconds(cold: bool, root: Path = ROOT) -> tuple[float, float]:
    """Seconds for a new interpreter to import the fuser and simulate half a second of flight, then to fuse it
    (the first ticks compile or load every kernel), after deleting numba's caches (``cold``) or with them in
    place; the code of the tree ``root``."""
    if cold:
        for f in numba_caches(root):
            f.unlink()
    out = subprocess.run([sys.executable, "-c", COMPILE_PROBE], cwd=root, capture_output=True, text=True, check=True)
    imported, fused = out.stdout.strip().splitlines()[-1].split()
    return float(imported), float(fused)


def compile_units_s(root: Path = ROOT) -> dict[str, float]:
    """CPU seconds of each compile (kernel and signature; numba's own overloads together) when a new interpreter
    fuses the probe's flight with an empty numba cache (a temporary ``NUMBA_CACHE_DIR``), code of the tree ``root``."""
    with tempfile.TemporaryDirectory() as cache:
        out = subprocess.run([sys.executable, "-c", UNITS_PROBE], cwd=root, capture_output=True, text=True, check=True,
                             env={**os.environ, "NUMBA_CACHE_DIR": cache})
    return json.loads(out.stdout.strip().splitlines()[-1])


def compile_units_table(trees: list[tuple[str, Path]]) -> list[list[str]]:
    """One column per tree: each compile's CPU seconds (:func:`compile_units_s`), largest first, and their sum."""
    units = [compile_units_s(root) for _, root in trees]
    keys = sorted({k for u in units for k in u}, key=lambda k: -max(u.get(k, 0.0) for u in units))
    rows = [["compile unit (cold, CPU s, each less the compiles nested in it)"] + [name for name, _ in trees]]
    rows += [[k] + [f"{u[k]:.2f}" if k in u else "-" for u in units] for k in keys]
    rows.append([f"sum ({' / '.join(str(len(u)) for u in units)} units)"] + [f"{sum(u.values()):.2f}" for u in units])
    return rows


def print_table(rows: list[list[str]]) -> None:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    fmt = lambda r: "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))) + " |"  # noqa: E731
    print(fmt(rows[0]))
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows[1:]:
        print(fmt(r))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="runs per log; the median and the fastest are printed (default: 5)")
    parser.add_argument("--skip-compile", action="store_true", help="skip the cold and warm compile measurement")
    parser.add_argument("--baseline", metavar="REF", help="measure git revision REF's code too, in the same run: its per-tick totals "
                        "just before and after this tree's, and its compile cost")
    parser.add_argument("--compile-units", action="store_true", help="only the cold compile's cost per kernel and signature "
                        "(with --baseline, REF's beside)")
    parser.add_argument("--totals-json", action="store_true", help=argparse.SUPPRESS)  # a --baseline child: the bare totals, as JSON
    parser.add_argument("logs", nargs="*", type=Path, help="logs (default: every MCAP in logs/)")
    args = parser.parse_args()
    logs = [log.resolve() for log in args.logs] or sorted((ROOT / "logs").glob("*.mcap"))
    if args.totals_json:
        print(json.dumps(tick_totals_us(logs, args.runs)))
        return 0
    with ExitStack() as stack:
        tree = stack.enter_context(baseline_tree(args.baseline)) if args.baseline else None
        if args.compile_units:
            print_table(compile_units_table(([(f"{args.baseline}'s code", tree)] if tree else []) + [("this tree", ROOT)]))
            return 0
        return measure(args, logs, tree)


def measure(args: argparse.Namespace, logs: list[Path], tree: Path | None) -> int:
    """Print the per-step table (and, with ``tree``, the baseline's totals beside this tree's), then the compile cost."""
    before = baseline_totals_us(tree, logs, args.runs) if tree else None
    overhead = timer_overhead_s()
    columns, totals = [], []
    for log in logs:
        config = config_for(log)
        ticks = captured_ticks(log, config)
        runs = bare_totals_us(config, ticks, 2 * args.runs if tree else args.runs)  # as many runs as the baseline's two sets
        columns.append((log.stem, len(ticks), split_by_step(config, ticks, overhead)))
        totals.append((statistics.median(runs), min(runs)))
    after = baseline_totals_us(tree, logs, args.runs) if tree else None
    steps = list(STEPS) + [OWN, PUBLISH]
    rows = [["us per tick"] + [f"{name} ({n:,} ticks)" for name, n, _ in columns]]
    rows += [[step] + [f"{split[step]:.1f}" for _, _, split in columns] for step in steps]
    rows.append(["sum of the steps (timed with the split)"] + [f"{sum(split.values()):.1f}" for _, _, split in columns])
    n_runs = 2 * args.runs if tree else args.runs
    rows.append([f"total, bare: median of {n_runs} runs"] + [f"{med:.1f}" for med, _ in totals])
    rows.append([f"total, bare: fastest of {n_runs} runs"] + [f"{fast:.1f}" for _, fast in totals])
    rows.append(["against the target"] + [f"{fast / TICK_TARGET_US:.2f}x of {TICK_TARGET_US:g} us" for _, fast in totals])
    if before is not None and after is not None:
        base = [min(before[log.name] + after[log.name]) for log in logs]
        rows.append([f"{args.baseline}'s code: fastest of {2 * args.runs} runs (before and after, same run)"] + [f"{b:.1f}" for b in base])
        rows.append([f"{args.baseline}'s / this tree's (fastest)"] + [f"{b / fast:.2f}x" for b, (_, fast) in zip(base, totals)])
    print_table(rows)
    print(f"\n(step timer's own cost, {overhead * 1e9:.0f} ns per wrapped call, taken off; shared machine: noisy figures)")
    if not args.skip_compile:
        table = [["compile (numba cache=True), new interpreter", "imports + simulate 0.5 s", "fuse it (kernels)", "total",
                  "target (kernels)"]]
        if tree is not None:
            table += compile_rows(tree, f"{args.baseline}'s code")
        table += compile_rows(ROOT, "this tree")
        print()
        print_table(table)
    return 0


def compile_rows(root: Path, name: str) -> list[list[str]]:
    """Cold (caches deleted) and warm (fastest of 3) start of the tree ``root``."""
    cold = compile_seconds(True, root)
    warm = min((compile_seconds(False, root) for _ in range(3)), key=sum)
    return [[f"{name}, cold: caches deleted ({len(numba_caches(root))} cache files written)", f"{cold[0]:.2f} s", f"{cold[1]:.2f} s",
             f"{sum(cold):.2f} s", f"< {COLD_TARGET_S:g} s"],
            [f"{name}, warm: from the cache (fastest of 3)", f"{warm[0]:.2f} s", f"{warm[1]:.2f} s", f"{sum(warm):.2f} s",
             f"< {WARM_TARGET_S:g} s"]]


if __name__ == "__main__":
    sys.exit(main())
