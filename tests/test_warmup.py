"""The live commands' warm-up (fuser/warmup.py) compiles every kernel a real flight's ticks call, before the clock.

Checked in a fresh interpreter: the numba dispatchers (and their type signatures) compiled by the warm-up alone,
against those a replay of the golden logs then adds. Any kernel or signature the replays compile that the warm-up
did not would be compiled inside a live run's first ticks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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
print(json.dumps({"warm_up": after_warm_up, "replays": compiled()}))
"""


def test_the_warm_up_compiles_what_the_replays_of_real_shaped_flights_call():
    logs = [str(ROOT / "logs" / name) for name in ("sim_aggressive.mcap", "sim_dropout.mcap", "px4_sample_cut.mcap")]
    out = subprocess.run([sys.executable, "-c", PROBE, *logs], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    warm, replays = result["warm_up"], result["replays"]
    assert sum(map(len, warm.values())) >= 10, warm  # the kernels exist and the warm-up reached them
    missing = {k: sorted(set(v) - set(warm.get(k, []))) for k, v in replays.items() if set(v) - set(warm.get(k, []))}
    assert not missing, missing
