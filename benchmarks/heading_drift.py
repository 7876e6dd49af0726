"""How a BROAD trial's heading error grows against what the fuser reports, per stretch of time (issue 15).

    python benchmarks/heading_drift.py ../shared/data/broad/32_disturbed_attached_magnet_1cm.hdf5 [--every 10]

The trial goes through the replay pipeline with the default configuration and the field the importer measures
(as ``benchmarks/broad.py`` runs it). For each stretch of ``--every`` seconds of movement it prints BROAD's heading
error (RMS and largest, against the motion-capture truth), the reported uncertainty (RMS angle of the published
Bingham), what the heading update did on most ticks (fused, or gated and why), and the gyro bias along the body's
vertical: the filter's estimate and its sigma. While the magnetometer is gated the heading is held on the gyro, so
the heading error can only grow with the bias error along the vertical; the sigma says how fast the filter thinks
it may grow.
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from broad import broad_errors, interp_quat  # noqa: E402
from core import quaternion as quat  # noqa: E402
from fuser.config import FuserConfig  # noqa: E402
from fuser.importers import broad_quat_from_ned  # noqa: E402
from fuser.pipeline import Pipeline  # noqa: E402
from fuser.replay import MAX_CATCH_UP_TICKS  # noqa: E402
from loto import FS_HZ, load_trial  # noqa: E402

DOWN = np.array([0.0, 0.0, 1.0])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trial", type=Path, help="a BROAD trial (.hdf5)")
    parser.add_argument("--every", type=float, default=10.0, help="seconds per row (default 10)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as work:
        trial = load_trial(args.trial, Path(work))
    pipeline = Pipeline(FuserConfig().replace(mag={"field_ned_gauss": trial.field_ned_gauss}), max_catch_up_ticks=MAX_CATCH_UP_TICKS)
    model, estimates, bias = pipeline.loop.model, [], {}
    step = model.step

    def step_noting_bias(tick):  # the bias along the body's vertical after each tick, by tick count
        result = step(tick)
        vertical = quat.to_matrix(result.published.mode).T @ DOWN  # world down in the body frame
        b = model.state.bias
        bias[len(bias) + 1] = (float(np.asarray(b.estimate_rad_s) @ vertical),
                               float(np.sqrt(vertical @ np.asarray(b.covariance_rad2_s2) @ vertical)))
        return result

    model.step = step_noting_bias  # type: ignore[method-assign]
    pipeline.outputs.append(estimates.append)
    for sample, receive_ns in trial.inputs:
        pipeline.feed(sample, receive_ns)
    pipeline.finish()

    ticks = [e for e in estimates if e.sensor_t_ns is not None and not e.predicted]
    x = np.array([e.sensor_t_ns for e in ticks]) * 1e-9 * FS_HZ
    inside = np.nonzero((x >= 0) & (x <= len(trial.q_es) - 1))[0]
    q_true, ok = interp_quat(trial.q_es, x[inside])
    idx = inside[ok]
    moving = trial.movement[np.round(x[idx]).astype(int)]
    heading = broad_errors(broad_quat_from_ned(np.array([ticks[i].q_wxyz for i in idx])), q_true[ok])["heading"]  # deg, >= 0
    t_s = x[idx] / FS_HZ
    print(f"{args.trial.stem}: heading error against the reported uncertainty, movement only (deg; bias deg/s)")
    print("| from s | heading RMS | heading max | reported | heading update (most ticks) | bias along vertical | its sigma |")
    print("|---|---|---|---|---|---|---|")
    for start in np.arange(0.0, t_s.max(), args.every):
        rows = [k for k in range(len(idx)) if moving[k] and start <= t_s[k] < start + args.every]
        if not rows:
            continue
        outcomes = collections.Counter(_heading_outcome(ticks[idx[k]]) for k in rows).most_common(1)[0]
        b = np.array([bias[ticks[idx[k]].counters["ticks"]] for k in rows])
        print(f"| {start:.0f} | {np.sqrt(np.mean(heading[rows] ** 2)):.2f} | {heading[rows].max():.2f} | "
              f"{np.mean([ticks[idx[k]].uncertainty_deg for k in rows]):.2f} | {outcomes[0]} ({outcomes[1]} of {len(rows)}) | "
              f"{np.degrees(b[:, 0].mean()):.4f} | {np.degrees(b[:, 1].mean()):.4f} |")
    return 0


def _heading_outcome(estimate) -> str:
    d = next((d for d in estimate.diagnostics if d["update"] == "heading"), None)
    return "none" if d is None else f"{d['outcome']} {d['reason']}".strip()


if __name__ == "__main__":
    sys.exit(main())
