"""Soak test of the Bingham filter: 10^6 consecutive random steps without NaN, exception or loss of orthonormality.

    python benchmarks/soak.py                 # 10^6 steps
    python benchmarks/soak.py --steps 10000   # the test suite's size
    python benchmarks/soak.py --seed 3

One :class:`core.filters.BinghamFilter` (saddlepoint normalizer, the
default) is driven through a seeded random sequence of operations:

* ``predict(noise, u)`` (progressive paper, Alg. 1) -- 40%;
* ``predict_nonlinear(g, noise)`` with ``g`` either ``x (x) u`` or the
  unscented paper's stabilizer (sec. V) towards a random goal, unscented
  sampler with random lambda -- 15%;
* ``update(z, noise)`` (unscented paper, sec. IV-B), the noise sometimes
  informing only one or two axes (zeros in ``Z``) -- 35%;
* ``update_likelihood`` (progressive paper, Alg. 2) of a vector
  measurement (``x n x*`` of a random unit ``n`` plus Gaussian noise), with
  the unscented sampler or RSS with m in {10, 50, 100} -- 10%.

Concentrations are drawn log-uniformly from ``|z| = 1e-3`` (near-uniform)
to ``1e6``; every 1000 steps, with probability 1/2, the state is replaced
by a random extreme (``|z|`` up to 1e6, or uniform). After every step the
script checks that ``M`` and ``Z`` are finite, ``M^T M = I`` to 1e-9,
``Z`` ascending with ``Z[-1] = 0``, and the estimate is a unit quaternion;
the first failure or exception stops the run with the step, the operation
and a reproducer (seed and step), and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import collections  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402

import numpy as np  # noqa: E402

from core import quaternion as quat  # noqa: E402
from core.bingham import Bingham  # noqa: E402
from core.filters import BinghamFilter  # noqa: E402
from core.rss import rss_samples  # noqa: E402

ORTHO_TOL = 1e-9
OPS = ("predict", "predict_nonlinear", "update", "update_likelihood")
OP_P = (0.40, 0.15, 0.35, 0.10)


def random_unit(rng: np.random.Generator, shape=()) -> np.ndarray:
    """Uniform unit quaternion(s)."""
    return quat.normalize(rng.standard_normal(shape + (4,)))


def random_z(rng: np.random.Generator, allow_zero: bool = False) -> np.ndarray:
    """Three concentrations, |z| log-uniform in [1e-3, 1e6]; with ``allow_zero`` some may be exactly 0."""
    z = -(10.0 ** rng.uniform(-3.0, 6.0, 3))
    if allow_zero and rng.random() < 0.3:
        z[rng.random(3) < 0.5] = 0.0
    return z


def random_noise(rng: np.random.Generator, allow_zero: bool = False) -> Bingham:
    """Noise with its mode at the identity (unscented paper, sec. IV-B) or, one time in five, anywhere."""
    mode = quat.IDENTITY if rng.random() < 0.8 else random_unit(rng)
    return Bingham.from_mode(mode, random_z(rng, allow_zero))


def stabilizer(goal: np.ndarray, a: float):
    """``g(x) = x (x) (x^-1 (x) y)^a`` (unscented paper, sec. V); odd in ``x``."""
    return lambda x: quat.multiply(x, quat.power(quat.multiply(quat.conjugate(x), goal), a))


def step(f: BinghamFilter, op: str, rng: np.random.Generator) -> None:
    """One random operation of kind ``op`` on ``f``."""
    if op == "predict":
        f.predict(random_noise(rng), random_unit(rng) if rng.random() < 0.5 else quat.from_rotvec(rng.normal(0, 0.05, 3)))
    elif op == "predict_nonlinear":
        u = random_unit(rng)
        g = stabilizer(random_unit(rng), rng.uniform(0.01, 0.99)) if rng.random() < 0.5 else (lambda x: quat.multiply(x, u))
        f.predict_nonlinear(g, random_noise(rng), "unscented", lam=rng.uniform(0.0, 0.95))
    elif op == "update":
        f.update(random_unit(rng), random_noise(rng, allow_zero=True))
    else:
        n = quat.normalize(rng.standard_normal(3).tolist() + [0.0])[:3]
        sigma = 10.0 ** rng.uniform(-3.0, 0.5)
        meas = quat.rotate(random_unit(rng), n) + rng.normal(0, sigma, 3)
        loglik = lambda x: -0.5 * np.sum((meas - quat.rotate(x, n)) ** 2, axis=-1) / sigma**2  # noqa: E731
        if rng.random() < 0.5:
            f.update_likelihood(loglik, tau=rng.uniform(0.05, 0.5), sampler="unscented")
        else:
            f.update_likelihood(loglik, tau=rng.uniform(0.05, 0.5), sampler="rss", m=int(rng.choice([10, 50, 100])))


def check(f: BinghamFilter) -> str | None:
    """Why the state is broken, or ``None``."""
    M, Z = f.state.M, f.state.Z
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(Z))):
        return f"non-finite state M={M} Z={Z}"
    dev = float(np.max(np.abs(M.T @ M - np.eye(4))))
    if dev > ORTHO_TOL:
        return f"M not orthonormal (max |M^T M - I| = {dev:.3g})"
    if np.any(np.diff(Z) < 0) or Z[-1] != 0.0:
        return f"Z not ascending with Z[-1] = 0: {Z}"
    est = f.estimate
    if not np.isfinite(est).all() or abs(np.linalg.norm(est) - 1.0) > 1e-9:
        return f"estimate not a unit quaternion: {est}"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10**6, help="number of steps (default 10^6)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--report-every", type=int, default=100_000, help="progress line every N steps")
    args = parser.parse_args()
    for m in (10, 50, 100):  # build the cached Dirac mixtures outside the timed loop
        rss_samples(Bingham.from_mode(quat.IDENTITY, [-5.0, -5.0, -5.0]), m)
    rng = np.random.default_rng(args.seed)
    f = BinghamFilter(Bingham.uniform())
    counts: collections.Counter[str] = collections.Counter()
    seconds: collections.Counter[str] = collections.Counter()
    max_abs_z, max_dev, uniform_like = 0.0, 0.0, 0
    start = time.perf_counter()
    for k in range(args.steps):
        if k % 1000 == 999 and rng.random() < 0.5:
            f.state = Bingham.uniform() if rng.random() < 0.2 else Bingham.from_mode(random_unit(rng), random_z(rng))
        op = OPS[rng.choice(len(OPS), p=OP_P)]
        t0 = time.perf_counter()
        try:
            step(f, op, rng)
        except Exception:  # noqa: BLE001 - the soak reports any exception with its step
            traceback.print_exc()
            print(f"FAIL: exception at step {k} in {op} (seed {args.seed}); state before: {f.state!r}")
            return 1
        seconds[op] += time.perf_counter() - t0
        counts[op] += 1
        problem = check(f)
        if problem:
            print(f"FAIL: {problem} at step {k} after {op} (seed {args.seed})")
            return 1
        max_abs_z = max(max_abs_z, float(-f.state.Z[0]))
        max_dev = max(max_dev, float(np.max(np.abs(f.state.M.T @ f.state.M - np.eye(4)))))
        uniform_like += float(-f.state.Z[0]) < 1.0
        if args.report_every and (k + 1) % args.report_every == 0:
            el = time.perf_counter() - start
            print(f"  {k + 1} steps, {el:.0f} s, {(k + 1) / el:.0f} steps/s", flush=True)
    elapsed = time.perf_counter() - start
    print(f"OK: {args.steps} steps, seed {args.seed}, {elapsed:.1f} s, {args.steps / elapsed:.0f} steps/s")
    print("| operation | count | us/op |")
    print("|---|---|---|")
    for op in OPS:
        print(f"| {op} | {counts[op]} | {1e6 * seconds[op] / max(counts[op], 1):.1f} |")
    print(f"largest |z| seen in the state: {max_abs_z:.3g}; near-uniform states (|z_1| < 1): {uniform_like}")
    print(f"largest |M^T M - I| seen: {max_dev:.3g} (tolerance {ORTHO_TOL:g}); no NaN, no exception")
    return 0


if __name__ == "__main__":
    sys.exit(main())
