"""Speed of the Bingham core against pyrecest, measured in the same run.

    python benchmarks/bench_core.py            # full table
    python benchmarks/bench_core.py --quick    # fewer repetitions

Prints microseconds per call (median over repeated batches, one thread) for
both normalization methods and for pyrecest's BinghamDistribution, with the
ratio pyrecest / ours-saddlepoint, plus numba's first-import compile time
with an empty cache and with a warm one (fresh processes).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402

from core import quaternion as quat  # noqa: E402
from core.bingham import Bingham, composition_inertia  # noqa: E402
from core.filters import BinghamFilter  # noqa: E402
from core.normalization import fit_dispersion, log_normalizer, moments  # noqa: E402

CASES = [np.array([-5.0, -3.0, -1.0, 0.0]), np.array([-400.0, -200.0, -50.0, 0.0]), np.array([-1e4, -1e4, -1e3, 0.0])]


def per_call_us(fn: Callable[[], object], budget_s: float) -> float:
    """Median microseconds per call over batches filling ``budget_s``."""
    fn()
    start = time.perf_counter()
    fn()
    once = max(time.perf_counter() - start, 1e-7)
    batch = max(1, int(0.02 / once))
    samples = []
    deadline = time.perf_counter() + budget_s
    while time.perf_counter() < deadline or len(samples) < 3:
        t0 = time.perf_counter()
        for _ in range(batch):
            fn()
        samples.append((time.perf_counter() - t0) / batch)
    return statistics.median(samples) * 1e6


def ours(method: str) -> dict[str, Callable[[Callable], float]]:
    """Operations of this project, each timed as the mean over CASES."""
    dists = [Bingham.from_mode(quat.normalize([1, 2, 3, 4]), z[:3]) for z in CASES]
    inertias = [composition_inertia(d.inertia(method), d.inertia(method)) for d in dists]
    noise = Bingham.from_mode(quat.IDENTITY, [-500.0, -500.0, -500.0])
    u = quat.from_rotvec([0.01, 0.02, 0.03])
    z_meas = quat.normalize([1.0, 0.1, 0.0, 0.0])

    def step(d: Bingham) -> None:
        f = BinghamFilter(d, method)
        f.predict(noise, u)
        f.update(z_meas, noise)

    return {
        "log_normalizer": lambda z: log_normalizer(z, method),
        "moments": lambda z: moments(z, method),
        "log_normalizer + moments": lambda z: (log_normalizer(z, method), moments(z, method)),
        "fit (Z from moments)": lambda i: fit_dispersion(np.sort(np.linalg.eigvalsh(inertias[i])), method),
        "Bingham.fit (eigh + fit)": lambda i: Bingham.fit(inertias[i], method),
        "compose + fit": lambda i: Bingham(dists[i].M, dists[i].Z).compose(dists[i], method),
        "unscented samples": lambda i: Bingham(dists[i].M, dists[i].Z).unscented_samples(method=method),
        "filter step (predict + update)": lambda i: step(Bingham(dists[i].M, dists[i].Z)),
    }


def pyrecest_ops() -> dict[str, Callable]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from pyrecest.distributions import BinghamDistribution as PB
    dists = [PB(z, np.eye(4)) for z in CASES]
    moments_ = [d.moment() for d in dists]
    return {
        "log_normalizer": lambda z: PB.calculate_F(z),
        "moments": lambda z: PB(z, np.eye(4)).moment(),
        "log_normalizer + moments": lambda z: PB(z, np.eye(4)).moment(),
        "Bingham.fit (eigh + fit)": lambda i: PB.fit_to_moment(moments_[i]),
        "compose + fit": lambda i: PB(CASES[i], np.eye(4)).compose(dists[i]),
        "unscented samples": lambda i: PB(CASES[i], np.eye(4)).sample_deterministic(0.5),
    }


def fresh_z(z: np.ndarray) -> Callable[[], np.ndarray]:
    """A new, slightly different z on every call, so that no cache (pyrecest
    memoizes its normalizer) turns the measurement into a dictionary lookup."""
    counter = iter(range(10**12))
    return lambda: z * (1.0 + 1e-9 * next(counter))


def time_over_cases(op: Callable, by_index: bool, budget_s: float) -> float:
    if by_index:
        return statistics.mean(per_call_us(lambda i=i: op(i), budget_s) for i in range(len(CASES)))
    return statistics.mean(per_call_us(lambda f=fresh_z(z): op(f()), budget_s) for z in CASES)


BY_INDEX = {"log_normalizer": False, "moments": False, "log_normalizer + moments": False}


def compile_times() -> tuple[float, float]:
    """Seconds for a fresh process to import core and run every kernel: empty numba cache, then warm."""
    code = (
        "import time; t=time.perf_counter(); import numpy as np; from core.bingham import Bingham;"
        "B=Bingham.fit(np.diag([0.1,0.2,0.3,0.4])); B.compose(B); print(time.perf_counter()-t)"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        run = lambda: float(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
        return run(), run()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="shorter timing budget per operation")
    args = parser.parse_args()
    budget = 0.05 if args.quick else 0.3
    cold, warm = compile_times()
    print(f"numba first import + first calls: {cold:.2f} s with an empty cache, {warm:.2f} s with a warm cache\n")
    sp_ops, ex_ops = ours("saddlepoint"), ours("exact")
    try:
        peer = pyrecest_ops()
    except ImportError:
        peer = {}
        print("pyrecest not installed (pip install '.[bench]'): its column is empty\n")
    header = f"{'operation':32s} {'saddlepoint us':>15s} {'exact us':>10s} {'pyrecest us':>12s} {'pyrecest/ours':>14s}"
    print(header)
    print("-" * len(header))
    for name in sp_ops:
        by_index = BY_INDEX.get(name, True)
        sp = time_over_cases(sp_ops[name], by_index, budget)
        ex = time_over_cases(ex_ops[name], by_index, budget / 3)
        if name in peer:
            pr = time_over_cases(peer[name], by_index, budget / 3)
            print(f"{name:32s} {sp:15.1f} {ex:10.1f} {pr:12.1f} {pr / sp:13.0f}x")
        else:
            print(f"{name:32s} {sp:15.1f} {ex:10.1f} {'-':>12s} {'-':>14s}")
    print("\nTargets (issue 3, one core): log_normalizer + moments < 20 us, fit < 100 us, compose + fit < 150 us.")


if __name__ == "__main__":
    main()
