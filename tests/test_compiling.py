"""A command that waits for numba's compiler says so, and a first replay's rate leaves the compiling out
(fuser/compiling.py).

On the first run after installing, the filter's kernels compile for about 30 s inside the first tick. A replay
printed "812 samples/s" for the PX4 sample where the next run printed 9,080, and said nothing while it waited.
Checked with kernels defined here (never cached, so each compiles on its first call) and with numba's own
compiles, against wall time measured around them."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numba
import pytest

from fuser import compiling
from fuser.config import FuserConfig

LOG = Path(__file__).resolve().parent.parent / "logs" / "sim_hover.mcap"


def _fresh_kernels():
    """An outer kernel calling an inner one, neither compiled yet (its compile nests the inner's)."""

    @numba.njit
    def inner(x):
        return x * 2.0 + 1.0

    @numba.njit
    def outer(x):
        return inner(x) - 1.0

    return outer


def test_a_compile_is_timed_once_and_a_loaded_kernel_is_not():
    outer = _fresh_kernels()
    with compiling.compile_watch() as first:
        start = time.perf_counter()
        assert outer(2.0) == 4.0
        wall = time.perf_counter() - start
    assert 0.0 < first.seconds <= wall  # the nested compile of `inner` is inside the outer one, not added to it
    with compiling.compile_watch() as again:
        assert outer(3.0) == 6.0  # compiled already: nothing to compile
    assert again.seconds == 0.0


def test_the_notice_comes_once_while_a_compile_runs_long(monkeypatch: pytest.MonkeyPatch):
    """Driven through numba's listener calls directly, so the compile lasts exactly as long as the test needs."""
    monkeypatch.setattr(compiling, "NOTICE_AFTER_S", 0.01)
    told = threading.Event()
    calls: list[int] = []
    watch = compiling.CompileWatch(lambda: calls.append(1) or told.set())
    watch.on_start(None)  # a compile that will run long
    watch.on_start(None)  # ...and the compile of a callee inside it
    assert told.wait(30.0)
    watch.on_end(None)
    watch.on_end(None)
    watch.on_start(None)  # a second long compile: the user has been told already
    time.sleep(0.1)
    watch.on_end(None)
    assert calls == [1]
    assert watch.seconds > 0.1


def test_a_quick_compile_says_nothing(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setattr(compiling, "NOTICE_AFTER_S", 0.5)
    calls: list[int] = []
    watch = compiling.CompileWatch(lambda: calls.append(1))
    watch.on_start(None)
    watch.on_end(None)  # over before the notice was due: the timer is cancelled
    time.sleep(1.0)
    assert calls == []


def test_the_warm_up_with_its_kernels_loaded_says_nothing(monkeypatch: pytest.MonkeyPatch):
    """Loading a kernel from the cache is not compiling: no notice even with no delay at all (the warm-up's
    notice was a wall-clock timer, which fired for any slow warm-up)."""
    from fuser.warmup import warm_up

    warm_up(FuserConfig())  # the kernels compiled or loaded in this process
    monkeypatch.setattr(compiling, "NOTICE_AFTER_S", 0.0)
    calls: list[int] = []
    assert warm_up(FuserConfig(), lambda: calls.append(1)) > 0.0
    time.sleep(0.2)
    assert calls == []


@pytest.fixture
def compiles_during_replay(monkeypatch: pytest.MonkeyPatch):
    """The replay's pipeline compiles a fresh kernel as it finishes, as a first run compiles the filter."""
    from fuser.pipeline import Pipeline

    finish = Pipeline.finish

    def compiling_finish(self):
        assert _fresh_kernels()(1.0) == 2.0
        return finish(self)

    monkeypatch.setattr(Pipeline, "finish", compiling_finish)


def test_a_replay_that_compiles_leaves_it_out_of_its_rate(tmp_path: Path, compiles_during_replay):  # noqa: ARG001
    from fuser.replay import replay

    summary = replay(LOG, tmp_path / "e.mcap", FuserConfig(), progress=None)
    assert 0.0 < summary.compile_seconds < summary.seconds
    assert summary.samples_per_s == pytest.approx(summary.samples / (summary.seconds - summary.compile_seconds))


@pytest.mark.parametrize("shown_after_s, said", [(1e-9, True), (1e9, False)])
def test_the_replay_line_says_how_long_it_compiled(tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch,
                                                   compiles_during_replay, shown_after_s: float, said: bool):  # noqa: ARG001
    from fuser import batch, cli

    monkeypatch.setattr(batch, "COMPILE_SHOWN_S", shown_after_s)
    assert cli.main(["replay", str(LOG), "-o", str(tmp_path / "e.mcap")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("replay:"))
    found = re.fullmatch(r"replay: (\d+) samples -> \d+ estimates in ([\d.]+) s \(([\d,]+) samples/s"
                         r"(?:; ([\d.]+) s of it compiling the filter)?\); .*e\.mcap", line)
    assert found is not None, line
    assert (found.group(4) is not None) == said, line


BATCH = """
import sys
from fuser import cli, compiling
compiling.NOTICE_AFTER_S = 0.0  # any compile at all is said
sys.exit(cli.main(sys.argv[1:]))
"""


def _cache_without_the_tick(folder: Path) -> dict[str, str]:
    """The environment of a process whose numba cache holds every kernel but the compiled tick (``fusion.tick``),
    which it must compile (a few seconds; the whole filter from nothing takes about 30)."""
    from fuser.warmup import warm_up

    warm_up(FuserConfig())  # this process's cache holds every kernel
    shutil.copytree(os.environ["NUMBA_CACHE_DIR"], folder)  # set per xdist worker by conftest.py
    ticks = list(folder.rglob("fusion.tick-*"))
    assert ticks, "no cached fusion.tick to remove"
    for path in ticks:
        path.unlink()
    return {**os.environ, "NUMBA_CACHE_DIR": str(folder)}


@pytest.mark.skipif("NUMBA_CACHE_DIR" not in os.environ, reason="needs the numba cache folder conftest.py sets under xdist")
def test_a_batch_in_processes_compiles_once_before_its_workers_and_says_so(tmp_path: Path):
    """Before, each worker of ``--jobs 2`` compiled the same kernels side by side without a word (measured from an
    empty cache, three logs: 30 s of wall, 54 s of CPU, and the summary's note of 54 s compiling); now the batch's
    own process compiles them once, says so, and the workers load them: no worker's rate leaves compiling out."""
    logs = [str(LOG), str(LOG.with_name("sim_magnet.mcap"))]
    run = subprocess.run([sys.executable, "-c", BATCH, "replay", *logs, "--out-dir", str(tmp_path / "out"), "--jobs", "2"],
                         capture_output=True, text=True, timeout=600, env=_cache_without_the_tick(tmp_path / "cache"))
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stderr.count(compiling.COMPILING) == 1, run.stderr
    assert "2 logs, 2 ok" in run.stdout, run.stdout
    assert "spent compiling" not in run.stdout, run.stdout  # the workers compiled nothing
