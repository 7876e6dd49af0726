#!/usr/bin/env python3
"""A real PX4 flight: the Bingham fuser, VQF and Madgwick against PX4 EKF2's attitude.

    python benchmarks/px4.py [--log ../shared/data/px4/sample.ulg] [--config FILE.toml] [--set group.key=value ...]

Data: ``sample.ulg`` from the pyulog project (github.com/PX4/pyulog, BSD-3-Clause). EKF2's
``vehicle_attitude`` is a reference, **not** ground truth: the table is the *difference* to EKF2.

* Bingham fuser: ``bingham-fuser import`` (MAVLink HIGHRES_IMU + ATTITUDE_QUATERNION -> MCAP) then
  :func:`fuser.replay.replay` with the same fixed configuration as ``benchmarks/broad.py``
  (the autopilot's attitude is *not* fused: ``attitude.mode`` is ``"off"``), reference field from
  the importer.
* VQF (defaults, 9-D, ``Ts`` = median sample interval) and Madgwick (ahrs, beta 0.12, per-sample dt)
  are fed the same FRD vectors; their earth frames (ENU for VQF; NWU for Madgwick, composed into ENU
  by ``broad.run_madgwick``) are composed into NED with the fixed rotation ``Q_NE``.
* Differences by :func:`fuser.evaluate.attitude_errors` (EKF2 slerped at each estimator's times):
  RMS total, tilt and heading, over the whole log after 1 s, the hand-held motion (1-7 s) and the
  still part (after 7 s).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from broad import PLOTS, RESULTS, parse_sets, run_fuser, run_madgwick, run_vqf, write_section  # noqa: E402

from core import quaternion as quat  # noqa: E402
from fuser.config import load_config  # noqa: E402
from fuser.evaluate import attitude_errors  # noqa: E402
from fuser.importers import PX4_ATTRIBUTION, Q_NE, read_px4  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PHASES = (("after 1 s", 1.0, 1e9), ("motion 1-7 s", 1.0, 7.0), ("still > 7 s", 7.0, 1e9))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", default=str(ROOT.parent / "shared" / "data" / "px4" / "sample.ulg"),
                    help="a PX4 ULog (default: pyulog's sample flight in ../shared/data/px4 beside the repository)")
    ap.add_argument("--config")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    try:
        import pyulog  # noqa: F401
    except ImportError:
        print("px4.py needs pyulog: pip install 'bingham-fuser[import]'", file=sys.stderr)
        return 2
    if not Path(args.log).is_file():
        print(f"no such file: {args.log} (give --log FILE: a PX4 ULog, e.g. pyulog's sample.ulg)", file=sys.stderr)
        return 2
    config = load_config(args.config, parse_sets(args.set))
    data = read_px4(args.log)
    print(f"PX4: {args.log}\n{PX4_ATTRIBUTION}\n", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        fr = run_fuser(data, config, Path(tmp), "px4")
    dts = np.diff(data.t_ns, prepend=data.t_ns[0] - int(np.median(np.diff(data.t_ns)))) * 1e-9
    ts = float(np.median(np.diff(data.t_ns))) * 1e-9
    q_v, vqf_s = run_vqf(data.gyro, data.accel, data.mag, ts)
    q_m, mad_s = run_madgwick(data.gyro, data.accel, data.mag, 1.0 / ts, dts)
    to_ned = lambda q: quat.multiply(np.broadcast_to(Q_NE, q.shape), q)  # noqa: E731
    runs = {
        "Bingham fuser": (fr.t_ns, fr.q_nb, fr.unc_deg, fr.seconds_per_sample),
        "VQF": (data.t_ns, to_ned(q_v), np.zeros(len(q_v)), vqf_s),
        "Madgwick": (data.t_ns, to_ned(q_m), np.zeros(len(q_m)), mad_s),
    }
    t0 = data.t_ns[0]
    lines = [
        "| estimator | " + " | ".join(f"{p[0]}: total / tilt / heading" for p in PHASES) + " | us / sample |",
        "|---|" + "---|" * (len(PHASES) + 1),
    ]
    errs = {}
    for name, (t, q, unc, sec) in runs.items():
        e = attitude_errors(t, q, unc, data.ref_t_ns, data.ref_q)
        errs[name] = e
        cells = []
        for _, a, b in PHASES:
            rel = (e.t_ns - t0) * 1e-9
            k = (rel >= a) & (rel < b)
            r = lambda v: float(np.sqrt(np.mean(v[k] ** 2)))  # noqa: E731
            cells.append(f"{r(e.total_deg):.2f} / {r(e.tilt_deg):.2f} / {r(e.heading_deg):.2f}")
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sec * 1e6:.1f} |")
    lines += ["", f"Difference to PX4 EKF2 `vehicle_attitude` in degrees (RMS); EKF2 is not ground truth. "
                  f"Fuser reference field {data.mag_field_ned_gauss} G ({data.field_source}). "
                  f"Fuser counters: {fr.counters}."]
    print("\n".join(lines))
    if not args.no_write:
        plot(errs, t0, PLOTS / "px4_sample.png")
        write_section(RESULTS, "px4", [f"### PX4 sample.ulg ({time.strftime('%Y-%m-%d')})", "", *lines, "",
                                       "![px4](broad_plots/px4_sample.png)"])
    return 0


def plot(errs, t0, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(9, 3.4), dpi=72)
    b = errs["Bingham fuser"]
    tb = (b.t_ns - t0) * 1e-9
    ax.fill_between(tb, 0, b.uncertainty_deg, color="C0", alpha=0.2, lw=0, label="Bingham RMS uncertainty")
    for i, (name, e) in enumerate(errs.items()):
        ax.plot((e.t_ns - t0) * 1e-9, e.total_deg, lw=0.7, color=f"C{i}", label=name)
    ax.set_ylim(0, 6)
    ax.set_xlabel("log time [s]")
    ax.set_ylabel("difference to EKF2 [deg]")
    ax.set_title("PX4 sample.ulg: total difference to EKF2 (not ground truth)", fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    fig.text(0.99, 0.01, "data: PX4/pyulog sample.ulg, BSD-3-Clause", ha="right", fontsize=6, color="0.4")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
