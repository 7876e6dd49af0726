"""Accuracy of the saddlepoint normalizer against the exact quadrature, by concentration.

    python benchmarks/accuracy_normalizer.py

The grid is the one the tests use: z = -(c, b, a, 0) for every ascending
triple of 16 values from 0 to 1e6 (816 points). Prints a Markdown table of
the relative errors of N and of the dispersion moments E[x_i^2], i < 4.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from core.normalization import log_normalizer, moments

VALUES = [0.0, 0.1, 0.5, 1, 2, 3, 5, 8, 10, 20, 50, 100, 1e3, 1e4, 1e5, 1e6]
# The error follows the least concentrated dispersion axis, so regimes go by the smallest abs(z_i), i < 4.
REGIMES = [("uniform to mild: smallest abs(z) <= 1", 0, 1), ("moderate: smallest in (1, 20]", 1, 20),
           ("concentrated: smallest in (20, 1e3]", 20, 1e3), ("extreme: smallest in (1e3, 1e6]", 1e3, 1e6)]


def main() -> None:
    rows = []
    for a, b, c in itertools.combinations_with_replacement(VALUES, 3):
        z = -np.array([c, b, a, 0.0])
        n_err = math.expm1(log_normalizer(z) - log_normalizer(z, "exact"))
        m_err = float(np.max(np.abs(moments(z)[:3] / moments(z, "exact")[:3] - 1)))
        rows.append((a, n_err, m_err, z))
    print("| regime | points | max abs(N error) | mean abs(N error) | max moment error | mean moment error |")
    print("|---|---|---|---|---|---|")
    for name, lo, hi in REGIMES:
        sel = [r for r in rows if lo < r[0] <= hi or (lo == 0 and r[0] <= hi)]
        n = np.abs([r[1] for r in sel])
        m = np.array([r[2] for r in sel])
        print(f"| {name} | {len(sel)} | {n.max():.2%} | {n.mean():.2%} | {m.max():.2%} | {m.mean():.2%} |")
    worst_n = max(rows, key=lambda r: abs(r[1]))
    worst_m = max(rows, key=lambda r: r[2])
    print(f"\nworst N error {worst_n[1]:+.2%} at z = {worst_n[3].tolist()}; worst moment error {worst_m[2]:.2%} at z = {worst_m[3].tolist()}")


if __name__ == "__main__":
    main()
