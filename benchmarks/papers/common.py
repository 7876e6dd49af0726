"""Scenario code shared by the paper reproductions in ``benchmarks/papers/``.

Quaternions are (w, x, y, z) everywhere in the project. The unscented and
saddlepoint papers write them (x, y, z, w) with the real part last; the only
place that order appears here is :func:`from_paper_xyzw`, used on the values
copied from the papers. The QBF and RSS papers already write w first.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from core import quaternion as quat  # noqa: E402
from core.baselines import Gaussian, ParticleFilter, QuaternionUKF  # noqa: E402
from core.bingham import Bingham  # noqa: E402
from core.filters import BinghamFilter  # noqa: E402

HERE = Path(__file__).resolve().parent

#: Goal state of the ball-joint scenario, (0.5, 0.5, 0.5, 0.5) in either order
#: (unscented paper, sec. V; saddlepoint paper, sec. IV-B).
GOAL = np.array([0.5, 0.5, 0.5, 0.5])


# -- conventions ---------------------------------------------------------------
def from_paper_xyzw(q: ArrayLike) -> NDArray[np.float64]:
    """A quaternion written (x, y, z, w) in the unscented/saddlepoint papers, as the project's (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def angular_error_deg(truth: ArrayLike, estimate: ArrayLike) -> NDArray[np.float64]:
    """Unscented paper, eq. (4): ``2 min(acos(x^T x_e), pi - acos(x^T x_e))`` in degrees (antipodal-aware)."""
    return np.degrees(quat.angular_distance(truth, estimate))


# -- the ball-joint stabilization system ---------------------------------------
def stabilizer(goal: ArrayLike, a: float) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """``g(x) = x (+) (x^-1 (+) y)^a`` of the unscented paper, sec. V (the saddlepoint paper's eq. with ``c``).

    The paper defines ``g`` on the hemisphere ``x . y >= 0`` and ``g(x) =
    -g(-x)`` on the other: :func:`core.quaternion.power` takes the rotation
    of ``x^-1 (+) y`` with ``w >= 0`` (the short way round), which is exactly
    that choice, so ``g(-x) = -g(x)`` holds for every row. Vectorised over rows.
    """
    y = quat.as_quaternion(goal)

    def g(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return quat.multiply(x, quat.power(quat.multiply(quat.conjugate(x), y), a))

    return g


def draw_projected_gaussian(gauss: Gaussian, n: int, rng: np.random.Generator) -> NDArray[np.float64]:
    """``w / ||w||`` for ``w ~ N(mean, cov)`` in R^4 (unscented paper, sec. V-A; QBF paper, sec. 6)."""
    return quat.normalize(rng.multivariate_normal(gauss.mean, gauss.cov, size=n, method="eigh"))


def bingham_of_projected_gaussian(gauss: Gaussian, rng: np.random.Generator, n: int = 10_000) -> Bingham:
    """Bingham matched to normalized Gaussian samples (unscented paper, sec. V-A: "we used 10 000 samples")."""
    return Bingham.from_samples(draw_projected_gaussian(gauss, n, rng))


def isotropic_gaussian(c: float, mean: ArrayLike = quat.IDENTITY) -> Gaussian:
    """``N(mean, c I)`` in R^4; ``c I`` is the same in either component order."""
    return Gaussian(np.asarray(mean, dtype=float), c * np.eye(4))


def simulate(
    x0: NDArray[np.float64],
    g: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    draw_w: Callable[[int], NDArray[np.float64]],
    draw_v: Callable[[int], NDArray[np.float64]],
    n_steps: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ground truth and measurements of ``x_(t+1) = g(x_t) (+) w_t``, ``z_t = x_t (+) v_t`` (unscented paper, sec. IV-V).

    ``draw_w(n)``/``draw_v(n)`` return ``n`` unit noise quaternions. Returns
    ``(truth, z)``, each (n_steps, 4), for t = 1..n_steps (x0 is not measured).
    """
    w, v = draw_w(n_steps), draw_v(n_steps)
    truth = np.empty((n_steps, 4))
    x = x0
    for t in range(n_steps):
        x = quat.normalize(quat.multiply(g(x[None])[0], w[t]))
        truth[t] = x
    return truth, quat.multiply(truth, v)


# -- Monte Carlo bookkeeping ---------------------------------------------------
@dataclass
class Tally:
    """Per-filter errors (runs x steps, degrees) and wall time."""

    errors: list[NDArray[np.float64]] = field(default_factory=list)
    seconds: float = 0.0
    steps: int = 0

    def add(self, errors: ArrayLike, seconds: float) -> None:
        e = np.asarray(errors, dtype=float)
        self.errors.append(e)
        self.seconds += seconds
        self.steps += e.size

    @property
    def array(self) -> NDArray[np.float64]:
        return np.stack(self.errors)

    @property
    def mean_deg(self) -> float:
        return float(self.array.mean())

    @property
    def rmse_deg(self) -> float:
        return float(np.sqrt(np.mean(self.array**2)))

    @property
    def ms_per_step(self) -> float:
        return 1e3 * self.seconds / max(self.steps, 1)


def run_filter(step: Callable[[int], NDArray[np.float64]], n_steps: int, truth: NDArray[np.float64]) -> tuple[NDArray, float]:
    """Call ``step(t)`` (one predict + update, returning the estimate) for every t; errors and seconds."""
    errors = np.empty(n_steps)
    start = time.perf_counter()
    estimates = [step(t) for t in range(n_steps)]
    seconds = time.perf_counter() - start
    errors[:] = angular_error_deg(truth, np.asarray(estimates))
    return errors, seconds


@dataclass(frozen=True)
class Noise:
    """One noise (or prior) in both forms: the Gaussian the baselines assume and the Bingham the Bingham filter assumes."""

    gauss: Gaussian
    bingham: Bingham


Stepper = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def make_stepper(
    name: str, g: Callable, prior: Noise, w: Noise, v: Noise, rng: np.random.Generator, lam: float = 0.5
) -> Stepper:
    """A filter of the unscented paper's sec. V-A comparison as ``step(z) -> estimate`` (predict, then update).

    ``"BF"`` / ``"BF-exact"``: Bingham filter, ``predict_nonlinear`` with the
    unscented sampler (sec. IV-A) and the closed-form update (sec. IV-B), with
    the saddlepoint or the exact normalizer; ``"UKF"``: quaternion UKF with
    the antipodal fix and renormalization; ``"PF-<n>"``: particle filter with
    resampling after every update and the Gaussian likelihood approximation.
    """
    if name in ("BF", "BF-exact"):
        bf = BinghamFilter(prior.bingham, "exact" if name == "BF-exact" else "saddlepoint")

        def step(z):
            bf.predict_nonlinear(g, w.bingham, "unscented", lam=lam)
            bf.update(z, v.bingham)
            return bf.estimate

        return step
    if name == "UKF":
        ukf = QuaternionUKF(prior.gauss)

        def step(z):
            ukf.predict(g, w.gauss)
            ukf.update(z, v.gauss)
            return ukf.estimate

        return step
    if name.startswith("PF-"):
        pf = ParticleFilter(prior.gauss, int(float(name[3:])), rng)

        def step(z):
            pf.predict(g, w.gauss)
            pf.update(z, v.gauss)
            return pf.estimate

        return step
    raise ValueError(f"unknown filter {name!r}")


def monte_carlo(
    names: list[str],
    n_runs: int,
    n_steps: int,
    g: Callable,
    x0_draw: Callable[[np.random.Generator], NDArray[np.float64]],
    truth_w: Callable[[int, np.random.Generator], NDArray[np.float64]],
    truth_v: Callable[[int, np.random.Generator], NDArray[np.float64]],
    prior: Noise,
    w: Noise,
    v: Noise,
    seed: int,
) -> tuple[dict[str, Tally], list[NDArray[np.float64]]]:
    """Run every filter on the same ``n_runs`` simulated trajectories (seeded per run); tallies and truths."""
    tallies = {name: Tally() for name in names}
    truths = []
    for run in range(n_runs):
        rng = np.random.default_rng([seed, run])
        x0 = x0_draw(rng)
        truth, z = simulate(x0, g, lambda n: truth_w(n, rng), lambda n: truth_v(n, rng), n_steps)
        truths.append(truth)
        for name in names:
            step = make_stepper(name, g, prior, w, v, np.random.default_rng([seed, run, 1]))
            errors, seconds = run_filter(lambda t: step(z[t]), n_steps, truth)
            tallies[name].add(errors, seconds)
    return tallies, truths


# -- command line and output ---------------------------------------------------
def parse_args(doc: str, extra: Callable[[argparse.ArgumentParser], None] | None = None) -> argparse.Namespace:
    """``--quick`` (smaller run) and ``--seed`` for every script."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="smaller run (for a smoke test)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    if extra is not None:
        extra(parser)
    return parser.parse_args()


def print_table(header: list[str], rows: list[list[object]], title: str = "") -> str:
    """Print and return a GitHub-markdown table (floats with 3 significant decimals)."""

    def fmt(v: object) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1e-2 or abs(v) >= 1e4 else f"{v:.3f}" if abs(v) < 10 else f"{v:.2f}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    text = (f"{title}\n\n" if title else "") + "\n".join(lines)
    print(text, flush=True)
    return text


def save_figure(fig, name: str) -> Path:
    """Save next to the scripts as ``<name>.png`` at a resolution that keeps it well under 200 kB."""
    path = HERE / f"{name}.png"
    fig.savefig(path, dpi=80)
    print(f"wrote {path} ({path.stat().st_size // 1024} kB)")
    return path


def matplotlib_pyplot():
    """pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
