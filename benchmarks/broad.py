#!/usr/bin/env python3
"""BROAD benchmark: the Bingham fuser (import -> replay, the user's code path) against VQF and Madgwick.

    python benchmarks/broad.py [--trials DIR] [--quick] [--config FILE.toml] [--set group.key=value ...]

Data: the BROAD benchmark (D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD - A Benchmark for Robust
Inertial Orientation Estimation", Data 6(7):72, 2021, doi:10.3390/data6070072; CC-BY-4.0), default
folder ../shared/data/broad beside the repository.

Per trial, in one process:

* **Bingham fuser**: ``bingham-fuser import`` (MAVLink encode/decode -> MCAP) then
  :func:`fuser.replay.replay` with one fixed :class:`FuserConfig` for all trials (defaults, or
  ``--config``/``--set``); the only per-trial value is the reference magnetic field the importer
  measures from the trial's first 2 s at rest (a site measurement, as VQF learns its own reference).
  Speed = replay wall time / samples (includes MCAP decode/encode).
* **VQF**: ``vqf.VQF(1/fs)`` with default parameters, 9-D, ``update(gyr, acc, mag)`` then
  ``getQuat9D()`` per sample (the real-time class, not the offline one). Its earth frame is ENU
  (checked: at rest the accelerometer maps to +z, the field to +y), so its quaternion is compared as is.
* **Madgwick**: ``ahrs.filters.Madgwick(frequency=fs, beta=0.12)``, ``updateMARG`` per sample,
  initialised from the first sample's accelerometer and magnetometer. Its earth frame is
  north-west-up (its field reference is (bx, 0, bz)): composed into ENU with the fixed rotation
  ``Q_E_NWU`` = +90 degrees about z.

Metric (BROAD's ``broad_utils.calculateRMSE``): error quaternion in the ENU earth frame,
``q_diff = q_est (x) q_opt^-1``; total = 2 acos|w|, heading = 2 atan|z / w|, inclination =
2 acos sqrt(w^2 + z^2); RMS over the samples where ``movement`` is true and ``opt_quat`` is finite.
Heading: BROAD's metric does **not** align heading per trial; its optical frame is aligned with the
magnetometer's ENU frame (measured here: the field maps to within 0.5 degrees of north), so the
comparison is direct, as the benchmark's own code does. The fuser is scored at its tick times
(``sensor_t_ns``, 100 Hz), the truth interpolated between the two neighbouring samples; VQF and
Madgwick at every sample.

Calibration (fuser only, movement phases): a Bingham's credible region of mass ``a`` is the superlevel
set ``{x: x^T C x >= t_a}``. The truth lies inside iff ``u = P(X^T C X > q^T C q) <= a``. For a
concentrated Bingham ``-2 X^T C X`` is chi-square with 3 degrees of freedom, so
``u ~= chi2.cdf(-2 q^T C q, 3)``; this is checked against Monte Carlo (``Bingham.sample``, ``MC_DRAWS`` draws)
on a random subset of ticks of each trial and the largest difference is reported. The mean
log-likelihood of the truth is ``Bingham.log_pdf`` (saddlepoint normaliser, density on S^3) on every
5th tick.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core import quaternion as quat  # noqa: E402
from core.bingham import Bingham  # noqa: E402
from fuser.config import FuserConfig, load_config  # noqa: E402
from fuser.evaluate import credible_level  # noqa: E402
from fuser.importers import BROAD_ATTRIBUTION, broad_quat_from_ned, broad_quat_to_ned, read_broad, write_mcap  # noqa: E402
from fuser.record import read_log  # noqa: E402
from fuser.replay import replay  # noqa: E402

Q_E_NWU = np.array([math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
"""North-west-up -> east-north-up: +90 degrees about z (north -> +y, west -> -x)."""
LEVELS = (0.5, 0.9, 0.95)
MC_DRAWS = 20_000  # Monte Carlo check of the credible regions: standard error <= 0.0035
RESULTS = ROOT / "benchmarks" / "RESULTS.md"
PLOTS = ROOT / "benchmarks" / "broad_plots"


# -- metric --------------------------------------------------------------------------------------
def broad_errors(q_est: np.ndarray, q_opt: np.ndarray) -> dict[str, np.ndarray]:
    """Per-sample total/heading/inclination error (deg) of sensor->ENU quaternions, BROAD's formulas."""
    q_est = quat.normalize(q_est)
    q_opt = quat.normalize(q_opt)
    d = quat.multiply(q_est, quat.conjugate(q_opt))
    w, z = np.abs(d[:, 0]), d[:, 3]
    return {
        "total": np.degrees(2 * np.arccos(np.clip(w, 0, 1))),
        "heading": np.degrees(2 * np.arctan(np.abs(z) / np.maximum(w, 1e-12))),
        "inclination": np.degrees(2 * np.arccos(np.clip(np.sqrt(d[:, 0] ** 2 + z**2), 0, 1))),
    }


def rmse(errors: dict[str, np.ndarray], keep: np.ndarray) -> dict[str, float]:
    return {k: float(np.sqrt(np.mean(v[keep] ** 2))) for k, v in errors.items()}


def interp_quat(q: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quaternions ``q`` (rows at integer positions) at fractional positions ``x``; (q, valid)."""
    lo = np.clip(np.floor(x).astype(int), 0, len(q) - 2)
    f = (x - lo)[:, None]
    a, b = q[lo], q[lo + 1]
    b = np.where(np.sum(a * b, axis=1, keepdims=True) < 0, -b, b)
    out = (1 - f) * a + f * b
    valid = np.all(np.isfinite(out), axis=1)
    out[~valid] = [1.0, 0.0, 0.0, 0.0]
    return quat.normalize(out), valid


# -- baselines -----------------------------------------------------------------------------------
def initial_nwu(acc: np.ndarray, mag: np.ndarray) -> np.ndarray:
    """Sensor -> north-west-up quaternion from one accelerometer and magnetometer sample (TRIAD)."""
    up = acc / np.linalg.norm(acc)
    north = mag - (mag @ up) * up
    north /= np.linalg.norm(north)
    west = np.cross(up, north)
    return quat.from_matrix(np.vstack([north, west, up]))  # rows: earth axes in sensor coordinates


def run_vqf(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None, ts: float) -> tuple[np.ndarray, float]:
    """VQF (real-time class, defaults) per sample: sensor -> ENU quaternions and seconds per sample."""
    from vqf import VQF

    v = VQF(ts)
    out = np.empty((len(gyr), 4))
    g, a = np.ascontiguousarray(gyr, dtype=float), np.ascontiguousarray(acc, dtype=float)
    m = None if mag is None else np.ascontiguousarray(mag, dtype=float)
    start = time.perf_counter()
    for i in range(len(g)):
        if m is None:
            v.update(g[i], a[i])
            out[i] = v.getQuat6D()
        else:
            v.update(g[i], a[i], m[i])
            out[i] = v.getQuat9D()
    return out, (time.perf_counter() - start) / len(g)


def run_madgwick(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray, fs: float, dts: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """ahrs Madgwick (beta 0.12) per sample: sensor -> ENU quaternions and seconds per sample."""
    from ahrs.filters import Madgwick

    mw = Madgwick(frequency=fs, beta=0.12)
    q = initial_nwu(acc[0], mag[0])
    out = np.empty((len(gyr), 4))
    start = time.perf_counter()
    for i in range(len(gyr)):
        q = mw.updateMARG(q, gyr[i], acc[i], mag[i], dt=None if dts is None else float(dts[i]))
        out[i] = q
    seconds = (time.perf_counter() - start) / len(gyr)
    return quat.multiply(np.broadcast_to(Q_E_NWU, out.shape), out), seconds


# -- the fuser through import -> replay ------------------------------------------------------------
@dataclass
class FuserRun:
    t_ns: np.ndarray
    q_nb: np.ndarray
    M: np.ndarray
    Z: np.ndarray
    unc_deg: np.ndarray
    seconds_per_sample: float
    replay_s: float
    import_s: float
    counters: dict = field(default_factory=dict)


def run_fuser(data, config: FuserConfig, workdir: Path, name: str) -> FuserRun:
    t0 = time.perf_counter()
    mcap_in = workdir / f"{name}.mcap"
    summary = write_mcap(data, mcap_in)
    import_s = time.perf_counter() - t0
    cfg = config.replace(mag={"field_ned_gauss": tuple(summary.mag_field_ned_gauss)})
    rs = replay(mcap_in, workdir / f"{name}_fused.mcap", cfg, progress=None)
    est = [e for e in read_log(workdir / f"{name}_fused.mcap").estimates() if e.sensor_t_ns is not None]
    return FuserRun(
        t_ns=np.array([e.sensor_t_ns for e in est], dtype=np.int64),
        q_nb=np.array([e.q_wxyz for e in est]),
        M=np.array([e.M for e in est]),
        Z=np.array([e.Z for e in est]),
        unc_deg=np.array([e.uncertainty_deg for e in est]),
        seconds_per_sample=rs.seconds / max(rs.samples, 1),
        replay_s=rs.seconds,
        import_s=import_s,
        counters=rs.counters,
    )


def calibration(M: np.ndarray, Z: np.ndarray, q_true: np.ndarray, rng: np.random.Generator, n_check: int = 40) -> dict:
    """Coverage of the 50/90/95 % credible regions, mean log-likelihood, and the MC check of the approximation."""
    y = np.einsum("nij,ni->nj", M, q_true)  # components of the truth along the principal directions
    s = np.sum(Z * y * y, axis=1)  # exponent x^T C x (<= 0, 0 at the mode), for the Monte Carlo check below
    u = credible_level(M, Z, q_true)
    out = {f"cov{int(a * 100)}": float(np.mean(u <= a)) for a in LEVELS}
    ll_idx = np.arange(0, len(M), 5)
    ll = [float(Bingham(M[i], Z[i]).log_pdf(q_true[i])) for i in ll_idx]
    out["loglik"] = float(np.mean(ll))
    out["loglik_median"] = float(np.median(ll))
    check = rng.choice(len(M), size=min(n_check, len(M)), replace=False)
    diffs = []
    for i in check:
        b = Bingham(M[i], Z[i])
        xs = b.sample(MC_DRAWS, rng)
        sx = np.sum(Z[i] * (xs @ M[i]) ** 2, axis=1)
        diffs.append(abs(float(np.mean(sx > s[i])) - u[i]))
    out["mc_max_diff"] = float(np.max(diffs)) if diffs else float("nan")
    out["mc_sq_diffs"], out["mc_checks"] = float(np.sum(np.square(diffs))), len(diffs)
    out["u"] = u
    return out


# -- one trial -------------------------------------------------------------------------------------
def run_trial(path: Path, config: FuserConfig, workdir: Path, duration: float | None, rng, plots: Path | None) -> dict:
    data = read_broad(path, 0.0, duration)
    fs = 1e9 / 3_500_000  # BROAD: 285.714 Hz, exactly 3500 us
    movement = data.extra["movement"]
    q_opt = data.extra["q_es"]
    valid = movement & np.all(np.isfinite(q_opt), axis=1)
    # raw sensor-frame data for the baselines (the importer's FRD vectors rotated back, exact)
    from fuser.importers import Q_SB

    back = lambda v: quat.rotate(np.broadcast_to(Q_SB, v.shape[:-1] + (4,)), v)  # noqa: E731
    gyr, acc, mag = back(data.gyro), back(data.accel), back(data.mag)

    fr = run_fuser(data, config, workdir, path.stem)
    x = fr.t_ns * 1e-9 * fs  # fractional sample index of each tick
    inside = (x >= 0) & (x <= len(q_opt) - 1)
    x = x[inside]
    q_true_es, ok = interp_quat(q_opt, x)
    near = np.clip(np.round(x).astype(int), 0, len(movement) - 1)
    keep_b = ok & movement[near]
    q_est_es = broad_quat_from_ned(fr.q_nb[inside])
    err_b = broad_errors(q_est_es, q_true_es)
    cal = calibration(fr.M[inside][keep_b], fr.Z[inside][keep_b], broad_quat_to_ned(q_true_es[keep_b]), rng)

    q_vqf, vqf_s = run_vqf(gyr, acc, mag, 1.0 / fs)
    q_mad, mad_s = run_madgwick(gyr, acc, mag, fs)
    q_opt_safe = np.where(np.isfinite(q_opt), q_opt, 0.0)
    q_opt_safe[~np.all(np.isfinite(q_opt), axis=1)] = [1.0, 0, 0, 0]
    err_v = broad_errors(q_vqf, q_opt_safe)
    err_m = broad_errors(q_mad, q_opt_safe)
    res = {
        "trial": path.stem,
        "bingham": rmse(err_b, keep_b),
        "vqf": rmse(err_v, valid),
        "madgwick": rmse(err_m, valid),
        "speed_us": {"bingham": fr.seconds_per_sample * 1e6, "vqf": vqf_s * 1e6, "madgwick": mad_s * 1e6},
        "realtime_x": (len(data.t_ns) / fs) / fr.replay_s,
        "calibration": {k: v for k, v in cal.items() if k != "u"},
        "unc_rms_deg": float(np.sqrt(np.mean(fr.unc_deg[inside][keep_b] ** 2))),
        "counters": {k: int(v) for k, v in fr.counters.items()},
        "samples": int(len(data.t_ns)),
    }
    if plots is not None:
        plot_trial(plots / f"{path.stem}.png", path.stem, x / fs, err_b["total"], fr.unc_deg[inside], keep_b, cal["u"],
                   np.arange(len(q_opt)) / fs, err_v["total"], err_m["total"], valid, movement)
    return res


def plot_trial(out: Path, title, t_b, e_b, unc_b, keep_b, u, t_s, e_v, e_m, valid, movement) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(9, 3.6), dpi=72)
    step = 3  # thin the 286 Hz baselines for a small PNG
    ax.fill_between(t_b, 0, np.where(keep_b, unc_b, np.nan), color="C0", alpha=0.2, lw=0, label="Bingham RMS uncertainty (1 sigma)")
    ax.plot(t_s[::step], np.where(valid, e_v, np.nan)[::step], lw=0.6, color="C1", label="VQF")
    ax.plot(t_s[::step], np.where(valid, e_m, np.nan)[::step], lw=0.6, color="C2", alpha=0.7, label="Madgwick (beta 0.12)")
    ax.plot(t_b, np.where(keep_b, e_b, np.nan), lw=0.7, color="C0", label="Bingham fuser")
    finish_error_plot(fig, ax, f"BROAD {title}", float(np.nanpercentile(np.where(keep_b, e_b, np.nan), 99.5)), out)


def finish_error_plot(fig, ax, title: str, top_deg: float, out: Path) -> None:
    """Axes, legend and the dataset's attribution of a trial's error-over-time plot; saved to ``out`` and closed."""
    import matplotlib.pyplot as plt

    ax.set_ylim(0, max(5.0, top_deg * 1.3))
    ax.set_xlabel("trial time [s]   (only the movement phases are scored)")
    ax.set_ylabel("total error vs opt_quat [deg]")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=7, ncol=2)
    fig.text(0.99, 0.01, "data: BROAD (Laidig et al. 2021), CC-BY-4.0", ha="right", fontsize=6, color="0.4")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


# -- report ----------------------------------------------------------------------------------------
def table(results: list[dict], config_note: str) -> list[str]:
    lines = [
        "| trial | Bingham total / heading / incl. | VQF total / heading / incl. | Madgwick total / heading / incl. | Bingham in 50 / 90 / 95 % region | mean log-lik. |",
        "|---|---|---|---|---|---|",
    ]
    f3 = lambda r: f"{r['total']:.2f} / {r['heading']:.2f} / {r['inclination']:.2f}"  # noqa: E731
    for r in results:
        c = r["calibration"]
        lines.append(f"| {r['trial']} | {f3(r['bingham'])} | {f3(r['vqf'])} | {f3(r['madgwick'])} | "
                     f"{100 * c['cov50']:.0f} / {100 * c['cov90']:.0f} / {100 * c['cov95']:.0f} | {c['loglik']:.1f} |")
    mean = lambda who, k: float(np.mean([r[who][k] for r in results]))  # noqa: E731
    m3 = lambda who: f"**{mean(who, 'total'):.2f}** / {mean(who, 'heading'):.2f} / {mean(who, 'inclination'):.2f}"  # noqa: E731
    cm = lambda k: float(np.mean([r["calibration"][k] for r in results]))  # noqa: E731
    lines.append(f"| **mean** | {m3('bingham')} | {m3('vqf')} | {m3('madgwick')} | "
                 f"{100 * cm('cov50'):.0f} / {100 * cm('cov90'):.0f} / {100 * cm('cov95'):.0f} | {cm('loglik'):.1f} |")
    sp = lambda who: float(np.mean([r["speed_us"][who] for r in results]))  # noqa: E731
    lines += [
        "",
        f"Speed per sample (mean over trials): Bingham fuser {sp('bingham'):.0f} us (full replay path incl. MCAP, "
        f"{np.mean([r['realtime_x'] for r in results]):.1f}x real time at 286 Hz), VQF {sp('vqf'):.1f} us (C++ behind a Python call), "
        f"Madgwick {sp('madgwick'):.0f} us (pure Python, ahrs).",
        f"Credible-region check: chi-square approximation vs Monte Carlo ({MC_DRAWS} draws, 40 ticks per trial): |difference| in the "
        f"tail probability RMS {math.sqrt(sum(r['calibration']['mc_sq_diffs'] for r in results) / sum(r['calibration']['mc_checks'] for r in results)):.4f}, largest "
        f"{max(r['calibration']['mc_max_diff'] for r in results):.3f} (Monte Carlo's own standard error: up to {0.5 / math.sqrt(MC_DRAWS):.4f}).",
        f"Fuser configuration: {config_note}",
    ]
    return lines


def write_section(path: Path, tag: str, lines: list[str], writer: str | None = None) -> None:
    """Replace (or append) the block between ``tag``'s markers in ``path``; ``writer`` names the command in the marker."""
    begin, end = f"<!-- {tag}:begin (written by {writer or f'benchmarks/{tag}.py'}) -->", f"<!-- {tag}:end -->"
    text = path.read_text() if path.exists() else "# Benchmarks on real data\n\n"
    block = "\n".join([begin, *lines, end])
    if begin in text and end in text:
        text = text[: text.index(begin)] + block + text[text.index(end) + len(end):]
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(text)


def parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        out[key] = tuple(json.loads(f"[{value}]")) if "," in value else json.loads(value)
    return out


def model_revision() -> str:
    """The git commit of the code measured, "+changes" if core/, drivers/ or fuser/ differ from it
    (the benchmark's own outputs, plots and RESULTS.md, do not count)."""
    import subprocess

    git = ["git", "-C", str(ROOT)]
    rev = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    changed = subprocess.run([*git, "diff", "--quiet", "HEAD", "--", "core", "drivers", "fuser"]).returncode != 0
    return (rev or "?") + ("+changes" if changed else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", default=str(ROOT.parent / "shared" / "data" / "broad"),
                    help="folder of BROAD .hdf5 trials (default: ../shared/data/broad beside the repository)")
    ap.add_argument("--quick", action="store_true", help="only the first 75 s of each trial, no plots, no RESULTS.md")
    ap.add_argument("--config", help="FuserConfig TOML (one parameter set for all trials)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a setting (JSON value; group.key, e.g. accel.lowpass_s=2)")
    ap.add_argument("--only", help="substring: run only matching trials")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--no-write", action="store_true", help="do not update benchmarks/RESULTS.md")
    ap.add_argument("--json", help="also dump the per-trial results here")
    ap.add_argument("--loto", action="store_true", help="leave-one-trial-out: fit on the other trials, score the held-out one "
                    "(benchmarks/loto.py); VQF only")
    ap.add_argument("--candidates", action="append", default=[], metavar="KEY=V1,V2",
                    help="with --loto: a filter setting fitted on the other trials among these values (repeatable)")
    args = ap.parse_args(argv)
    try:
        import h5py  # noqa: F401
        import vqf  # noqa: F401
        import ahrs  # noqa: F401
    except ImportError as exc:
        print(f"broad.py needs h5py, vqf and ahrs: pip install 'bingham-fuser[import,bench]' ({exc})", file=sys.stderr)
        return 2
    sets = parse_sets(args.set)
    config = load_config(args.config, sets)
    trials = sorted(Path(args.trials).glob("*.hdf5"))
    if args.only:
        trials = [t for t in trials if args.only in t.name]
    if not trials:
        print(f"no .hdf5 trials in {args.trials} (give --trials FOLDER: BROAD's data_hdf5, https://github.com/dlaidig/broad)",
              file=sys.stderr)
        return 2
    print(f"BROAD: {len(trials)} trials from {args.trials}\n{BROAD_ATTRIBUTION}\n", flush=True)
    if args.loto:
        return main_loto(args, trials, config, sets)
    rng = np.random.default_rng(0)
    results = []
    plots = None if (args.quick or args.no_plots) else PLOTS
    with tempfile.TemporaryDirectory() as tmp:
        for path in trials:
            start = time.perf_counter()
            r = run_trial(path, config, Path(tmp), 75.0 if args.quick else None, rng, plots)
            results.append(r)
            b, v, m, c = r["bingham"], r["vqf"], r["madgwick"], r["calibration"]
            print(f"{r['trial']:38s} total/heading/incl  Bingham {b['total']:5.2f} {b['heading']:5.2f} {b['inclination']:5.2f} | "
                  f"VQF {v['total']:5.2f} {v['heading']:5.2f} {v['inclination']:5.2f} | Madgwick {m['total']:5.2f} {m['heading']:5.2f} {m['inclination']:5.2f} | "
                  f"cover 50/90/95 {100 * c['cov50']:.0f}/{100 * c['cov90']:.0f}/{100 * c['cov95']:.0f} ll {c['loglik']:.1f} | "
                  f"{r['speed_us']['bingham']:.0f}/{r['speed_us']['vqf']:.1f}/{r['speed_us']['madgwick']:.0f} us/sample | {time.perf_counter() - start:.0f} s",
                  flush=True)
    rev = model_revision()
    note = f"model at git {rev or '?'}; " + ("defaults" if not (args.config or sets) else f"{args.config or ''} {sets}") + \
        " + per-trial reference field measured by the importer from the first 2 s"
    lines = table(results, note)
    print("\n".join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    if not (args.quick or args.no_write):
        write_section(RESULTS, "broad", [f"### BROAD ({len(results)} trials, {time.strftime('%Y-%m-%d')})", "",
                                         "RMSE in degrees over the movement phases (BROAD's metric, no heading alignment).", "", *lines])
    return 0


def main_loto(args, trials: list[Path], config: FuserConfig, sets: dict) -> int:
    import loto  # noqa: PLC0415 - imports this module

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        result = loto.run(trials, config, loto.parse_candidates(args.candidates), Path(tmp), log=lambda m: print(m, flush=True))
    given = ("defaults" if not (args.config or sets) else f"{args.config or ''} {sets}".strip())
    note = (f"model at git {model_revision()}; {given}" + (f"; fitted among {args.candidates}" if args.candidates else "")
            + "; the per-trial reference field measured by the importer from the first 2 s")
    lines = loto.table(result, note)
    print("\n".join(lines))
    print(f"({time.perf_counter() - start:.0f} s)")
    if args.json:
        Path(args.json).write_text(json.dumps(result["per_trial"], indent=1))
    if not args.no_write:
        figures = [] if args.no_plots else loto.plots(result, PLOTS)
        write_section(RESULTS, "broad_loto", [f"### BROAD, leave one trial out ({len(trials)} trials, {time.strftime('%Y-%m-%d')})", "",
                                              "RMSE in degrees over the movement phases (BROAD's metric, no heading alignment); every "
                                              "fitted parameter fitted on the other trials (benchmarks/loto.py).", "", *lines, "",
                                              *[f"![{p.stem}](broad_plots/{p.name})" for p in figures]],
                      "benchmarks/broad.py --loto")
    return 0


if __name__ == "__main__":
    sys.exit(main())
