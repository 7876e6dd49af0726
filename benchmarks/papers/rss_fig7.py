"""RSS paper, sec. IV, Fig. 7: Bingham filter with RSS-100 vs UT-7 vs progressive UT-7 under three measurement noises.

    python benchmarks/papers/rss_fig7.py           # 100 runs x 50 steps per noise level
    python benchmarks/papers/rss_fig7.py --quick   # 10 runs x 50 steps

Scenario (RSS paper, sec. IV, eqs. 14-15; the paper writes w first):
``x_k = x_(k-1) (x) u_(k-1) (x) w_(k-1)`` with ``w ~ Bingham`` of parameter
matrix ``C_B = -diag(1, 10, 10, 10)`` (mode at the identity, i.e.
concentrations (-9, -9, -9) after the shift of eq. 3 of the saddlepoint
paper), and the vector measurement ``z_k = x_k (x) n0 (x) x_k* + v_k``,
``v ~ N(0, a diag(1, 10, 10))``, ``a`` in {1e-1, 1e-2, 1e-4}; 100 Monte Carlo
runs of 50 steps. Not given in the paper, chosen here: ``n0 = (1, 0, 0)``
(the progressive paper's initial orientation, sec. V-B), a constant input
``u`` (0.2 rad about the axis (1, 2, 3)), truth ``x_0`` drawn from the
system noise's distribution around the identity, which is also every
filter's prior, and ``tau = 0.1`` for the progression (eq. 15).

Filters (all predict in closed form, progressive paper Alg. 1): RSS-100 and
UT-7 reweight their samples by the likelihood in one step (the RSS paper's
"non-progressive filtering scheme with only a sampling-approximation-based
update step": ``update_likelihood`` with ``max_steps=1``); UT-Prog-7 is
the progressive update (progressive paper, Alg. 2). The rotation about
``n0`` is unobservable from this measurement, so besides the orientation
error (eq. 4 of the unscented paper) the table gives the pointing error,
the angle between the true and estimated ``x n0 x*``, which the
measurement does inform. Fig. 7 is a box plot with no numbers in the text;
its claim is that RSS-100 is the most accurate at every level and that
UT-7 "almost totally failed" at low noise.
"""

from __future__ import annotations

import time

import numpy as np

from common import angular_error_deg, matplotlib_pyplot, parse_args, print_table, save_figure
from core import quaternion as quat
from core.bingham import Bingham
from core.filters import BinghamFilter
from core.rss import rss_samples

N0 = np.array([1.0, 0.0, 0.0])
SHAPE = np.array([1.0, 10.0, 10.0])
LEVELS = [1e-1, 1e-2, 1e-4]
NOISE = Bingham.from_mode(quat.IDENTITY, [-9.0, -9.0, -9.0])
U = quat.from_axis_angle([1.0, 2.0, 3.0], 0.2)
#: name -> keyword arguments of ``BinghamFilter.update_likelihood``.
FILTERS = {
    "RSS-100": dict(sampler="rss", m=100, max_steps=1),
    "UT-7": dict(sampler="unscented", max_steps=1),
    "UT-Prog-7": dict(sampler="unscented", tau=0.1),
}


def pointing_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle in degrees between ``p n0 p*`` and ``q n0 q*``."""
    a, b = quat.rotate(p, N0), quat.rotate(q, N0)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def simulate(n_steps: int, level: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Truth (x_1..x_n) and vector measurements of eqs. (14)-(15)."""
    x = NOISE.sample(1, rng)[0]
    w = NOISE.sample(n_steps, rng)
    truth = np.empty((n_steps, 4))
    for k in range(n_steps):
        x = quat.multiply(quat.multiply(x, U), w[k])
        truth[k] = x
    z = quat.rotate(truth, N0) + rng.normal(size=(n_steps, 3)) * np.sqrt(level * SHAPE)
    return truth, z


def log_likelihood(z: np.ndarray, level: float):
    """``log f_v(z - x n0 x*)`` up to a constant, over rows of quaternions (RSS paper, sec. IV)."""
    inv_var = 1.0 / (level * SHAPE)

    def loglik(x: np.ndarray) -> np.ndarray:
        d = z - quat.rotate(x, N0)
        return -0.5 * (d * d) @ inv_var

    return loglik


def main() -> None:
    args = parse_args(__doc__)
    n_runs, n_steps = (10, 50) if args.quick else (100, 50)
    rss_samples(NOISE, 100)  # builds the cached Dirac mixture once, outside the timing
    per_run = {}  # (level, name) -> (orientation errors per run, pointing errors per run)
    seconds = {name: 0.0 for name in FILTERS}
    start = time.perf_counter()
    for level in LEVELS:
        runs = {name: ([], []) for name in FILTERS}
        for run in range(n_runs):
            rng = np.random.default_rng([args.seed, run, int(-np.log10(level))])
            truth, z = simulate(n_steps, level, rng)
            for name, kwargs in FILTERS.items():
                bf = BinghamFilter(NOISE)
                est = np.empty((n_steps, 4))
                t0 = time.perf_counter()
                for k in range(n_steps):
                    bf.predict(NOISE, U)
                    bf.update_likelihood(log_likelihood(z[k], level), **kwargs)
                    est[k] = bf.estimate
                seconds[name] += time.perf_counter() - t0
                runs[name][0].append(angular_error_deg(truth, est).mean())
                runs[name][1].append(pointing_deg(truth, est).mean())
        for name in FILTERS:
            per_run[(level, name)] = tuple(np.array(v) for v in runs[name])
    rows = []
    for level in LEVELS:
        for name in FILTERS:
            orient, point = per_run[(level, name)]
            q1, med, q3 = np.percentile(point, [25, 50, 75])
            rows.append([f"{level:g}", name, float(med), f"{q1:.2f}-{q3:.2f}", float(np.percentile(point, 90)),
                         float(point.mean()), float(np.median(orient))])
    print_table(
        ["a", "filter", "pointing err median (deg)", "IQR", "90th pct", "mean", "orientation err median"],
        rows,
        f"RSS paper Fig. 7: per-run mean errors over {n_runs} runs x {n_steps} steps, seed {args.seed}",
    )
    n_total = len(LEVELS) * n_runs * n_steps
    print("ms per step (predict + update): " + ", ".join(f"{k} {1e3 * s / n_total:.2f}" for k, s in seconds.items()))
    print(f"total {time.perf_counter() - start:.1f} s")

    plt = matplotlib_pyplot()
    fig, axes = plt.subplots(1, len(LEVELS), figsize=(12, 3.8), sharey=True)
    for ax, level in zip(axes, LEVELS):
        ax.boxplot([per_run[(level, n)][1] for n in FILTERS])
        ax.set_xticks(range(1, len(FILTERS) + 1), list(FILTERS))
        ax.set_title(f"a = {level:g}")
        ax.set_yscale("log")
    axes[0].set_ylabel("per-run mean pointing error (deg)")
    fig.suptitle("Bingham filters under three measurement-noise levels (cf. RSS paper, Fig. 7)")
    fig.tight_layout()
    save_figure(fig, "rss_fig7")


if __name__ == "__main__":
    main()
