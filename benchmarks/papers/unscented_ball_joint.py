"""Unscented paper, sec. V-A: ball-joint stabilization, Bingham filter vs UKF vs particle filters.

    python benchmarks/papers/unscented_ball_joint.py           # 100 runs x 100 steps per noise level
    python benchmarks/papers/unscented_ball_joint.py --quick   # 10 runs x 100 steps

System and measurement (sec. V-A)::

    x_(t+1) = x_t (+) (x_t^-1 (+) y)^a (+) w_t / ||w_t||,   z_t = x_t (+) v_t / ||v_t||

with ``y = (0.5, 0.5, 0.5, 0.5)``, ``a = 0.1`` (the text's "exponent u"),
``w ~ N(mu_w, 0.001 I)``, ``v ~ N(mu_v, C_v)``, ``C_v = 0.003 I`` (low
noise) or ``0.3 I`` (high noise), all means the identity (paper
``[0, 0, 0, 1]``, real part last). Ground truth starts at ``x_0 ~ N(mu_0,
0.01 I)`` normalized. Every filter starts from ``N(mu_e, I)`` with ``mu_e =
[1, 0, 0, 0]`` in the paper's (x, y, z, w) order, i.e. the quaternion
``i`` = (0, 1, 0, 0) here (a 180 degree rotation; with ``C_e = I`` the prior
is nearly uniform anyway). The Bingham filter's noises and prior are
matched to 10 000 normalized Gaussian samples each; it predicts with the
7 unscented samples (lambda = 0.5, sec. III/IV-A) and updates in closed
form (sec. IV-B). The UKF and the particle filters (30, 300, 10^4
particles) get the Gaussians directly and the paper's antipodal fixes
(:mod:`core.baselines`). Reported: mean angular error (eq. 4) over all runs
and steps (Fig. 2), angular RMSE (Fig. 3), and milliseconds per filter step
(predict + update; the paper: 5.5 ms BF, 3.3 ms UKF, 45 ms PF-300 in Matlab).
"""

from __future__ import annotations

import time

import numpy as np

from common import (
    GOAL,
    Noise,
    bingham_of_projected_gaussian,
    draw_projected_gaussian,
    from_paper_xyzw,
    isotropic_gaussian,
    matplotlib_pyplot,
    monte_carlo,
    parse_args,
    print_table,
    save_figure,
    stabilizer,
)

A = 0.1
C_0, C_W = 0.01, 0.001
LEVELS = {"low": 0.003, "high": 0.3}
MU_E = from_paper_xyzw([1.0, 0.0, 0.0, 0.0])
FILTERS = ["BF", "UKF", "PF-30", "PF-300", "PF-1e4"]


def scenario(c_v: float, rng: np.random.Generator) -> tuple[Noise, Noise, Noise]:
    """Prior, system noise and measurement noise, each as the Gaussian and its matched Bingham (sec. V-A)."""
    forms = [isotropic_gaussian(1.0, MU_E), isotropic_gaussian(C_W), isotropic_gaussian(c_v)]
    return tuple(Noise(g, bingham_of_projected_gaussian(g, rng)) for g in forms)


def main() -> None:
    args = parse_args(__doc__)
    n_runs, n_steps = (10, 100) if args.quick else (100, 100)
    g = stabilizer(GOAL, A)
    truth_x0 = isotropic_gaussian(C_0)
    rows, results = [], {}
    start = time.perf_counter()
    for level, c_v in LEVELS.items():
        prior, w, v = scenario(c_v, np.random.default_rng([args.seed, 99]))
        tallies, truths = monte_carlo(
            FILTERS,
            n_runs,
            n_steps,
            g,
            lambda rng: draw_projected_gaussian(truth_x0, 1, rng)[0],
            lambda n, rng: draw_projected_gaussian(w.gauss, n, rng),
            lambda n, rng: draw_projected_gaussian(v.gauss, n, rng),
            prior,
            w,
            v,
            args.seed,
        )
        results[level] = (tallies, truths)
        for name, t in tallies.items():
            last = t.array[:, n_steps // 2 :]
            rows.append([f"{level} (C_v={c_v} I)", name, t.mean_deg, t.rmse_deg, float(last.mean()), t.ms_per_step])
    print_table(
        ["noise", "filter", "mean err (deg)", "RMSE (deg)", "mean err, steps 51-100", "ms/step"],
        rows,
        f"Unscented paper sec. V-A: {n_runs} runs x {n_steps} steps, seed {args.seed}",
    )
    print(f"total {time.perf_counter() - start:.1f} s")

    plt = matplotlib_pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    steps = np.arange(1, n_steps + 1)
    for ax, level in zip(axes[:2], LEVELS):
        tallies, _ = results[level]
        for name, t in tallies.items():
            ax.plot(steps, t.array.mean(axis=0), label=name, lw=1.2)
        ax.set_title(f"{level} noise, C_v = {LEVELS[level]} I: mean error per step")
        ax.set_xlabel("time step")
        ax.set_ylabel("mean angular error (deg)")
        ax.set_yscale("log")
    axes[0].legend(fontsize=8)
    names = list(results["high"][0])
    x = np.arange(len(names))
    for k, level in enumerate(LEVELS):
        axes[2].bar(x + 0.4 * k, [results[level][0][n].rmse_deg for n in names], 0.4, label=f"{level} noise")
    axes[2].set_xticks(x + 0.2, names)
    axes[2].set_ylabel("angular RMSE (deg)")
    axes[2].set_title("angular RMSE (cf. Fig. 3)")
    axes[2].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, "unscented_ball_joint")


if __name__ == "__main__":
    main()
