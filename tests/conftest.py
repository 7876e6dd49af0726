"""The suite's numba cache per xdist worker, and its hypothesis profiles.

**numba's cache, one per worker.** numba names a kernel's compiled overloads ``NAME.1.nbc``, ``NAME.2.nbc``...
by the index it reads just before saving (numba/core/caching.py, ``IndexDataCacheFile.save``): two processes
that compile different signatures of one kernel at once can both take ``.1``, and the index can then map one
signature to the other's machine code, which every later process would load and run. The tests call kernels
from Python with other argument types than the tick does, in two workers at once. Not seen to happen (30
forced runs of two processes compiling 30 kernels in two signatures each: every result right), but a property
test failed once in CI and once here with a cold cache and two workers, and neither reproduced warm or alone;
this is a way to get there that costs nothing to close. Each worker keeps its own cache (``.numba_cache/gw0``,
``gw1``, or ``gw0``, ``gw1`` under an exported ``NUMBA_CACHE_DIR``), set here before anything imports numba and
inherited by the processes a test starts. The product is not exposed: it calls each kernel with one signature
(``tests/test_warmup.py``), and processes compiling the same signature write the same entry.

**Hypothesis.** ``ci`` (the default) makes every property test draw the same examples on every run and every machine
(``derandomize``), so a test that passed here passes in CI and a failure there is reproducible here. It
reports the first failing example with its reproduction blob at once, without shrinking it: shrinking a
long stream through the compiled loop can outlast pytest-timeout's 300 s, and the timeout then hides the
failure behind hypothesis's "inconsistent data generation" (seen once in CI on test_fuser_any_input.py).

``search`` draws fresh random examples, shrinks what fails and explains it, for a wider search run by hand:

    python -m pytest -n 0 --timeout 0 --hypothesis-profile search tests/test_fuser_any_input.py

(or ``--hypothesis-seed N`` with it, to repeat one search). Tests that set ``max_examples`` keep their own
count in both profiles; ``search`` multiplies the others' by ten.
"""

from __future__ import annotations

import os
from pathlib import Path

from hypothesis import Phase, settings

if "PYTEST_XDIST_WORKER" in os.environ:  # under a cache directory given in the environment, each worker its own below it
    _cache = Path(os.environ.get("NUMBA_CACHE_DIR") or Path(__file__).resolve().parent.parent / ".numba_cache")
    os.environ["NUMBA_CACHE_DIR"] = str(_cache / os.environ["PYTEST_XDIST_WORKER"])

settings.register_profile(
    "ci", derandomize=True, print_blob=True, phases=(Phase.explicit, Phase.reuse, Phase.generate)
)
settings.register_profile("search", derandomize=False, print_blob=True, max_examples=1_000)
settings.load_profile("ci")
