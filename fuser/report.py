"""Scores and plots of a fused log: estimates against the truth or the autopilot's attitude.

Estimates carry ``sensor_t_ns``, the tick time on the vehicle's clock, so
they are compared with the truth (simulator, imported benchmark) or the
autopilot's own attitude at exactly that time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.samples import AttitudeSample
from fuser.evaluate import AttitudeErrors, attitude_errors
from fuser.record import read_log

__all__ = ["errors_of_log", "score_log", "write_report"]


def errors_of_log(path: str | Path) -> tuple[str, AttitudeErrors] | None:
    """(reference name, errors) for a log's estimates, or None if it has no reference or no estimates."""
    contents = read_log(path)
    estimates = [e for e in contents.estimates() if e.sensor_t_ns is not None]
    if not estimates:
        return None
    truth = contents.truth()
    if truth:
        name, ref = "truth", truth
    else:
        ref = [(s.t_ns, s.q_wxyz) for s, _ in contents.inputs() if isinstance(s, AttitudeSample)]
        name = "autopilot attitude"
        if len(ref) < 2:
            return None
    ref_t = np.array([t for t, _ in ref], dtype=np.int64)
    ref_q = np.array([q for _, q in ref], dtype=float)
    t = np.array([e.sensor_t_ns for e in estimates], dtype=np.int64)
    q = np.array([e.q_wxyz for e in estimates], dtype=float)
    unc = np.array([e.uncertainty_deg for e in estimates], dtype=float)
    return name, attitude_errors(t, q, unc, ref_t, ref_q)


def score_log(path: str | Path, since_s: float = 5.0) -> list[str]:
    """Lines of a summary table: RMS errors after the first ``since_s`` seconds (convergence)."""
    result = errors_of_log(path)
    if result is None:
        return [f"{path}: no reference attitude to score against"]
    name, err = result
    if err.t_ns.size == 0:
        return [f"{path}: no estimate within the time span of the {name} to score against"]
    if (err.t_ns[-1] - err.t_ns[0]) * 1e-9 <= since_s:
        since_s = 0.0  # too short to leave out the convergence: score all of it
    rms = err.rms(since_s)
    window = f"after the first {since_s:g} s" if since_s > 0 else "over the whole flight, convergence included"
    return [
        f"error against {name} {window} (RMS, degrees):",
        f"  total {rms['total']:.2f}   tilt {rms['tilt']:.2f}   heading {rms['heading']:.2f}   "
        f"reported uncertainty {rms['uncertainty']:.2f}",
    ]


def write_report(path: str | Path, out_dir: Path) -> list[str]:
    """Write ``attitude.png`` and ``error.png`` into ``out_dir``; return the summary lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    result = errors_of_log(path)
    lines = score_log(path)
    if result is None:
        return lines
    name, err = result
    out_dir.mkdir(parents=True, exist_ok=True)
    t = (err.t_ns - err.t_ns[0]) * 1e-9
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(t, err.total_deg, lw=0.8, label="total")
    ax[0].plot(t, err.tilt_deg, lw=0.8, label="tilt")
    ax[0].plot(t, err.heading_deg, lw=0.8, label="heading")
    ax[0].set_ylabel(f"error vs {name} [deg]")
    ax[0].legend(loc="upper right")
    ax[1].plot(t, err.total_deg, lw=0.8, label="actual error")
    ax[1].fill_between(t, 0, err.uncertainty_deg, alpha=0.3, label="reported RMS uncertainty")
    ax[1].set_ylabel("deg")
    ax[1].set_xlabel("time [s]")
    ax[1].legend(loc="upper right")
    fig.suptitle(Path(path).name)
    fig.tight_layout()
    fig.savefig(out_dir / "error.png", dpi=100)
    plt.close(fig)
    return lines + [f"plots: {out_dir / 'error.png'}"]
