#!/usr/bin/env python3
"""Fit the published model error (``fuser/model_error.py``) on the BROAD trials, with leave-one-out.

The model error is a consider term: it widens the published Bingham and
never feeds back into the filter. So the filter is run once per trial with
no model error (through the importer and the same pipeline as replay), the
state and the recent rotation rate of every tick are kept, and any
parameter set ``(heading floor, tilt floor, rate constant)`` is then scored
exactly, offline, on the movement phases:

* **mean log-likelihood** of the truth (a proper scoring rule), with the
  concentrated-limit density ``sum z_i y_i^2 + 1/2 sum log|z_i|`` (the
  Bingham log-density up to a constant for large ``|z|``; ``benchmarks/broad.py``
  reports the exact one), averaged per trial, then over trials;
* **coverage** of the 50/90/95 % credible regions (``-2 x^T C x`` against
  chi-square with 3 degrees of freedom, as in ``benchmarks/broad.py``),
  averaged the same way.

It prints the maximum-likelihood set, the maximum-likelihood set among those
whose three coverages lie within ``--within`` points of nominal (issue 7's
criterion), the configured defaults, and leave-one-trial-out figures for
both fits (each trial scored with the parameters fitted on the others).

Data: BROAD (Laidig et al., *Data* 6(7):72, 2021, doi:10.3390/data6070072, CC-BY-4.0).

    python benchmarks/fit_model_error.py          # ~2 min on the 8 shared trials
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import chi2

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from fuser.config import FuserConfig, ModelErrorSettings  # noqa: E402
from fuser.importers import BROAD_ATTRIBUTION  # noqa: E402
from fuser.model.params import PARAMS_DTYPE  # noqa: E402
from fuser.model_error import model_error_variances, widened_concentrations  # noqa: E402

LEVELS = np.array([0.5, 0.9, 0.95])
THRESHOLDS = chi2.ppf(LEVELS, 3)
HEADING_DEG = np.arange(0.5, 5.01, 0.25)
TILT_DEG = np.arange(0.0, 0.51, 0.05)
RATE_S = np.arange(0.0, 0.00401, 0.00025)


@dataclass
class TrialStates:
    """The unwidened filter state, recent rotation rate and truth at each scored tick of one trial."""

    name: str
    M: np.ndarray
    Z: np.ndarray
    rate_sq: np.ndarray
    q_true: np.ndarray


def settings_record(params: ModelErrorSettings) -> np.void:
    """``params`` as the model reads them: the ``model_error`` group of the parameters record (:mod:`fuser.model.params`;
    its three floats copied, not a whole configuration built: the grid scores thousands of sets)."""
    out = np.zeros(1, PARAMS_DTYPE["model_error"])[0]
    for name in out.dtype.names:
        out[name] = getattr(params, name)
    return out


def score(trial: TrialStates, params: ModelErrorSettings) -> tuple[np.ndarray, float]:
    """Coverage (%) of the 50/90/95 % regions and mean log-likelihood (up to a constant) of the truth."""
    tilt, heading = model_error_variances(settings_record(params), trial.rate_sq, heading_floor=True)
    z = widened_concentrations(trial.M, trial.Z, tilt[:, None], heading[:, None])
    y = np.einsum("nij,ni->nj", trial.M[:, :, :3], trial.q_true)
    exponent = np.sum(z * y * y, axis=1)
    coverage = 100.0 * np.mean(-2.0 * exponent[:, None] <= THRESHOLDS, axis=0)
    loglik = float(np.mean(exponent + 0.5 * np.sum(np.log(np.abs(z)), axis=1)))
    return coverage, loglik


def grid_scores(trials: list[TrialStates]) -> tuple[list[tuple[float, float, float]], np.ndarray, np.ndarray]:
    """Every parameter set of the grid with its per-trial coverage (sets x trials x 3) and log-likelihood."""
    params, cov, ll = [], [], []
    for h in HEADING_DEG:
        for t in TILT_DEG:
            for r in RATE_S:
                candidate = ModelErrorSettings(heading_deg=float(h), tilt_deg=float(t), rate_s=float(r))
                scores = [score(trial, candidate) for trial in trials]
                params.append((float(h), float(t), float(r)))
                cov.append([c for c, _ in scores])
                ll.append([l for _, l in scores])
    return params, np.array(cov), np.array(ll)


def best(cov: np.ndarray, ll: np.ndarray, fit_on: np.ndarray, within: float | None) -> int:
    """Index of the set with the highest mean log-likelihood on ``fit_on`` trials (optionally with every
    mean coverage within ``within`` points of nominal there; if no set is, the one whose largest deviation from
    nominal is smallest: the best calibrated, not the grid's first)."""
    objective = ll[:, fit_on].mean(axis=1)
    if within is None:
        return int(np.argmax(objective))
    deviation = np.abs(cov[:, fit_on].mean(axis=1) - 100.0 * LEVELS).max(axis=1)
    if not np.any(deviation <= within):
        return int(np.argmin(deviation))
    return int(np.argmax(np.where(deviation <= within, objective, -np.inf)))


def describe(label: str, p: tuple[float, float, float], cov: np.ndarray, ll: np.ndarray) -> str:
    c = cov.mean(axis=0)
    return (f"{label:34s} heading {p[0]:4.2f} deg  tilt {p[1]:4.2f} deg  rate {1e3 * p[2]:4.2f} ms | "
            f"cover {c[0]:4.1f} / {c[1]:4.1f} / {c[2]:4.1f} | log-lik {ll.mean():6.3f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", default=str(ROOT.parent / "shared" / "data" / "broad"), help="folder of BROAD .hdf5 trials")
    ap.add_argument("--within", type=float, default=5.0, help="coverage tolerance in points for the constrained fit")
    args = ap.parse_args(argv)
    paths = sorted(Path(args.trials).glob("*.hdf5"))
    if not paths:
        print(f"no .hdf5 trials in {args.trials}", file=sys.stderr)
        return 2
    print(f"BROAD: {len(paths)} trials from {args.trials}\n{BROAD_ATTRIBUTION}\n", flush=True)
    from loto import load_trial, run_ticks, scored  # noqa: PLC0415 - loto imports this module's fit

    with tempfile.TemporaryDirectory() as tmp:
        trials = [scored(t, run_ticks(t, FuserConfig())).at_time for t in (load_trial(p, Path(tmp)) for p in paths)]
    params, cov, ll = grid_scores(trials)
    n = len(trials)
    everyone = np.ones(n, bool)
    default = ModelErrorSettings()
    scores = [score(t, default) for t in trials]
    d = (default.heading_deg, default.tilt_deg, default.rate_s)
    print(describe("configured defaults", d, np.array([c for c, _ in scores]), np.array([l for _, l in scores])))
    for label, within in (("maximum likelihood", None), (f"max. likelihood, within {args.within:g} points", args.within)):
        i = best(cov, ll, everyone, within)
        print(describe(label, params[i], cov[i], ll[i]))
        held = [best(cov, ll, np.arange(n) != k, within) for k in range(n)]
        loo_cov = np.array([cov[j, k] for k, j in enumerate(held)])
        loo_ll = np.array([ll[j, k] for k, j in enumerate(held)])
        print(f"  leave one trial out: cover {' / '.join(f'{c:4.1f}' for c in loo_cov.mean(axis=0))} | log-lik {loo_ll.mean():6.3f}")
        for k, t in enumerate(trials):
            h = params[held[k]]
            print(f"    {t.name:36s} in-sample {' / '.join(f'{c:3.0f}' for c in cov[i, k])}   held out "
                  f"{' / '.join(f'{c:3.0f}' for c in loo_cov[k])} (fit on the others: {h[0]:.2f} deg, {h[1]:.2f} deg, {1e3 * h[2]:.2f} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
