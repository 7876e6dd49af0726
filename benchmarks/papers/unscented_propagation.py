"""Unscented paper, sec. V-B (Fig. 4): error of the mode of g(x) propagated by deterministic samples.

    python benchmarks/papers/unscented_propagation.py           # 10^7-sample ground truth
    python benchmarks/papers/unscented_propagation.py --quick   # 10^6-sample ground truth

``x ~ Bingham(I, -diag(b, b, b, 0))`` in the paper's (x, y, z, w) order,
i.e. mode at the identity and ``z = (-b, -b, -b)`` on the vector part, for
``b = 25, 50, 100``; ``g`` is the ball-joint stabilizer of sec. V
(:func:`common.stabilizer`) towards ``y = (0.5, 0.5, 0.5, 0.5)`` with
magnitude ``a``. Ground truth: the spherical mean (principal eigenvector of
the inertia) of ``g`` applied to exact Bingham draws, made zero-mean in the
spherical sense by pairing each draw ``x`` with its mirror ``x*`` (the
conjugate, which has the same distribution here), drawn in chunks of 10^6
to keep memory low. Proposed method: the 7 unscented samples (sec. III)
for each ``lambda``, pushed through ``g``, re-approximated by a Bingham
(moment matching), its mode. RSS-100 (the RSS paper's sampler,
``core.rss``) is added as one more row. Error: angle (eq. 4) between the
modes, in degrees. The Monte Carlo floor is half the angle between the
modes of the two halves of the ground-truth sample.
"""

from __future__ import annotations

import time

import numpy as np

from common import GOAL, angular_error_deg, matplotlib_pyplot, parse_args, print_table, save_figure, stabilizer
from core import quaternion as quat
from core.bingham import Bingham
from core.filters import deterministic_samples

BS = [25.0, 50.0, 100.0]
AS = [0.1, 0.3, 0.5, 0.7, 0.9]
LAMBDAS = [0.1, 0.3, 0.5, 0.7, 0.9]
CHUNK = 1_000_000


def ground_truth(b: float, n: int, rng: np.random.Generator) -> tuple[dict[float, np.ndarray], dict[float, float]]:
    """Modes of ``g_a(x)`` from ``n`` mirrored draws per ``a`` and each mode's Monte Carlo floor (degrees)."""
    dist = Bingham.from_mode(quat.IDENTITY, [-b, -b, -b])
    halves = {a: [np.zeros((4, 4)), np.zeros((4, 4))] for a in AS}
    done = 0
    while done < n:
        k = min(CHUNK, n - done) // 2
        for half, x in enumerate(np.array_split(dist.sample(k, rng), 2)):
            x = np.concatenate([x, quat.conjugate(x)])
            for a in AS:
                y = stabilizer(GOAL, a)(x)
                halves[a][half] += y.T @ y
        done += 2 * k
    modes, floors = {}, {}
    for a, (s0, s1) in halves.items():
        mode = lambda s: np.linalg.eigh(s)[1][:, -1]  # noqa: E731
        modes[a] = mode(s0 + s1)
        floors[a] = 0.5 * float(angular_error_deg(mode(s0), mode(s1)))
    return modes, floors


def propagated_mode(dist: Bingham, a: float, sampler: str, lam: float = 0.5) -> np.ndarray:
    """Mode of the Bingham matched to the deterministic samples of ``dist`` pushed through ``g_a`` (sec. V-B)."""
    points, weights = deterministic_samples(dist, sampler, m=100, lam=lam)
    return Bingham.from_samples(stabilizer(GOAL, a)(points), weights).mode


def main() -> None:
    args = parse_args(__doc__)
    n = 10**6 if args.quick else 10**7
    rows, errs = [], {}
    start = time.perf_counter()
    for b in BS:
        truth, floor = ground_truth(b, n, np.random.default_rng([args.seed, int(b)]))
        dist = Bingham.from_mode(quat.IDENTITY, [-b, -b, -b])
        for a in AS:
            row = [b, a]
            for lam in LAMBDAS:
                e = float(angular_error_deg(truth[a], propagated_mode(dist, a, "unscented", lam)))
                errs[(b, a, lam)] = e
                row.append(e)
            e_rss = float(angular_error_deg(truth[a], propagated_mode(dist, a, "rss")))
            errs[(b, a, "rss")] = e_rss
            rows.append(row + [e_rss, floor[a]])
    print_table(
        ["b", "a"] + [f"UT lam={lam}" for lam in LAMBDAS] + ["RSS-100", "MC floor"],
        rows,
        f"Unscented paper sec. V-B: mode error (deg) vs {n:.0e}-sample ground truth, seed {args.seed}",
    )
    print(f"total {time.perf_counter() - start:.1f} s")

    plt = matplotlib_pyplot()
    fig, axes = plt.subplots(1, len(BS), figsize=(13, 3.8), sharey=True)
    for ax, b in zip(axes, BS):
        for lam in LAMBDAS:
            ax.plot(AS, [errs[(b, a, lam)] for a in AS], marker="o", label=f"UT, lambda={lam}")
        ax.plot(AS, [errs[(b, a, "rss")] for a in AS], "k--", marker="s", label="RSS-100")
        ax.set_title(f"b = {b:g}")
        ax.set_xlabel("a")
        ax.set_yscale("log")
    axes[0].set_ylabel("mode error (deg)")
    axes[0].legend(fontsize=7)
    fig.suptitle("Propagation error of the mode of g(x) (cf. unscented paper, Fig. 4)")
    fig.tight_layout()
    save_figure(fig, "unscented_propagation")


if __name__ == "__main__":
    main()
