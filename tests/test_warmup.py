"""The live commands' warm-up (fuser/warmup.py) compiles every kernel a real flight's ticks call, before the clock;
and each kernel is compiled once.

Checked in a fresh interpreter with an empty numba cache: every numba dispatcher of ``core`` and ``fuser`` (found
through the garbage collector, so that none bound only inside another module or a closure is missed) with its type
signatures, after the warm-up alone and after replays of golden logs. Any kernel or signature the replays compile
that the warm-up did not would be compiled inside a live run's first ticks.

The tick is one compiled function (:func:`fuser.model.fusion.tick`) calling compiled functions in each module: a
function with two signatures was compiled twice, each time with everything it calls. numba specializes a function
once per *literal* argument value (``f(x, 0)`` and ``f(x, n)`` are ``Literal[int](0)`` and ``int64``; ``True`` and
``False`` two more), and once per array kind (a record's field is a ``nestedarray``, ``np.empty`` an ``array``; a
read-only or non-contiguous array, an int for a float): each a whole extra compile on a fresh install. A helper
inlined into its caller (``inline="always"``) that has a signature of its own was compiled on its own as well."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

PROBE = r"""
import gc, json, sys
from numba.core.registry import CPUDispatcher

def dispatchers():
    return [o for o in gc.get_objects() if isinstance(o, CPUDispatcher) and o.py_func.__module__.startswith(("core.", "fuser.", "drivers."))]

def name(d):
    return f"{d.py_func.__module__}.{d.py_func.__qualname__}"

def compiled():
    out = {}
    for d in dispatchers():
        code = d.py_func.__code__
        arguments = code.co_varnames[:code.co_argcount]
        out.setdefault(name(d), []).extend([[f"{a}: {t}" for a, t in zip(arguments, sig)] for sig in d.signatures])
    return out

from fuser.config import FuserConfig
from fuser.warmup import warm_up
warm_up(FuserConfig())
after_warm_up = compiled()
inlined = sorted({name(d) for d in dispatchers() if d.targetoptions.get("inline") == "always"})
from fuser.record import read_log, INPUT_TOPICS
from fuser.codec import decode_sample, loads
from fuser.pipeline import Pipeline
for log in sys.argv[1:]:
    pipeline = Pipeline(FuserConfig())
    for m in read_log(log).of(INPUT_TOPICS):
        pipeline.feed(*decode_sample(m.topic, loads(m.data)))
    pipeline.finish()
print(json.dumps({"warm_up": after_warm_up, "replays": compiled(), "inlined": inlined}))
"""

@pytest.fixture(scope="module")
def compiled(tmp_path_factory) -> dict:
    """What the warm-up, then replays of three golden logs (simulated and PX4), compiled in a fresh interpreter
    with an empty numba cache (a kernel loaded from the cache does not show what its callees were compiled for)."""
    logs = [str(ROOT / "logs" / name) for name in ("sim_aggressive.mcap", "sim_dropout.mcap", "px4_sample_cut.mcap")]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path_factory.mktemp("numba_cache"))}
    out = subprocess.run([sys.executable, "-c", PROBE, *logs], capture_output=True, text=True, cwd=ROOT, timeout=900, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _twice(signatures: dict[str, list[list[str]]]) -> dict[str, list[str]]:
    """Each kernel with more than one signature: the arguments whose types differ, each with its types."""
    out = {}
    for name, sigs in signatures.items():
        if len(sigs) > 1:
            differing = [i for i in range(len(sigs[0])) if len({str(s[i]) for s in sigs}) > 1]
            out[name] = [" | ".join(s[i] for s in sigs) for i in differing] or [" | ".join(map(str, sigs))]
    return out


def test_the_warm_up_compiles_what_the_replays_of_real_shaped_flights_call(compiled):
    warm, replays = compiled["warm_up"], compiled["replays"]
    assert sum(map(len, warm.values())) >= 10, warm  # the kernels exist and the warm-up reached them
    assert len(warm.get("fuser.model.fusion.tick", [])) == 1, warm.get("fuser.model.fusion.tick")  # the compiled tick ran
    missing = {k: [s for s in v if s not in warm.get(k, [])] for k, v in replays.items() if any(s not in warm.get(k, []) for s in v)}
    assert not missing, missing


def test_each_kernel_is_compiled_once(compiled):
    """After the warm-up flight (GNSS included), and after the replays, every dispatcher of ``core`` and ``fuser``
    has at most one signature: each kernel the tick calls is compiled once."""
    for stage in ("warm_up", "replays"):
        twice = _twice(compiled[stage])
        assert not twice, f"after the {stage.replace('_', '-')}, compiled more than once: " + "; ".join(
            f"{name} ({', '.join(args)})" for name, args in sorted(twice.items()))


def test_inlined_helpers_are_not_compiled_on_their_own(compiled):
    replays, inlined = compiled["replays"], compiled["inlined"]
    assert len(inlined) >= 5, inlined  # the helpers are marked (the check below is not vacuous)
    on_their_own = {name: replays[name] for name in inlined if replays.get(name)}
    assert not on_their_own, on_their_own
