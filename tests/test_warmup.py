"""The live commands' warm-up (fuser/warmup.py) compiles every kernel a real flight's ticks call, before the clock;
and each kernel is compiled once.

Checked in a fresh interpreter: the numba dispatchers (and their type signatures) compiled by the warm-up alone,
against those a replay of the golden logs then adds. Any kernel or signature the replays compile that the warm-up
did not would be compiled inside a live run's first ticks. A kernel with two signatures was compiled twice (a
literal argument, a read-only or non-contiguous array, an int for a float: each a whole extra compile on a fresh
install), and a helper inlined into its caller (``inline="always"``) that has a signature of its own was compiled
on its own as well."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

PROBE = r"""
import json, sys
from numba.core.dispatcher import Dispatcher
import core.bingham_kernels, core.saddlepoint, core.observations, fuser.model_error, fuser.model.velocity

def compiled():
    out = {}
    for module in [m for name, m in list(sys.modules.items()) if name.startswith(("core", "fuser", "drivers"))]:
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher):
                out[f"{value.py_func.__module__}.{value.py_func.__qualname__}"] = sorted(map(str, value.signatures))
    return out

def inlined():
    return sorted(f"{value.py_func.__module__}.{value.py_func.__qualname__}"
                  for module in [m for name, m in list(sys.modules.items()) if name.startswith(("core", "fuser"))]
                  for value in vars(module).values()
                  if isinstance(value, Dispatcher) and value.targetoptions.get("inline") == "always")

from fuser.config import FuserConfig
from fuser.warmup import warm_up
warm_up(FuserConfig())
after_warm_up = compiled()
from fuser.record import read_log, INPUT_TOPICS
from fuser.codec import decode_sample, loads
from fuser.pipeline import Pipeline
for log in sys.argv[1:]:
    pipeline = Pipeline(FuserConfig())
    for m in read_log(log).of(INPUT_TOPICS):
        pipeline.feed(*decode_sample(m.topic, loads(m.data)))
    pipeline.finish()
print(json.dumps({"warm_up": after_warm_up, "replays": compiled(), "inlined": inlined()}))
"""


@pytest.fixture(scope="module")
def compiled(tmp_path_factory) -> dict:
    """What the warm-up, then replays of three golden logs (simulated and PX4), compiled in a fresh interpreter
    with an empty numba cache (a kernel loaded from the cache does not show what its callees were compiled for)."""
    logs = [str(ROOT / "logs" / name) for name in ("sim_aggressive.mcap", "sim_dropout.mcap", "px4_sample_cut.mcap")]
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path_factory.mktemp("numba_cache"))}
    out = subprocess.run([sys.executable, "-c", PROBE, *logs], capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_warm_up_compiles_what_the_replays_of_real_shaped_flights_call(compiled):
    warm, replays = compiled["warm_up"], compiled["replays"]
    assert sum(map(len, warm.values())) >= 10, warm  # the kernels exist and the warm-up reached them
    missing = {k: sorted(set(v) - set(warm.get(k, []))) for k, v in replays.items() if set(v) - set(warm.get(k, []))}
    assert not missing, missing


def test_each_kernel_is_compiled_once(compiled):
    replays, inlined = compiled["replays"], compiled["inlined"]
    twice = {name: sigs for name, sigs in replays.items() if len(sigs) > 1}
    assert not twice, twice
    assert len(inlined) >= 5, inlined  # the helpers are marked (the check below is not vacuous)
    on_their_own = {name: replays[name] for name in inlined if replays.get(name)}
    assert not on_their_own, on_their_own

