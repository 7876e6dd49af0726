#!/usr/bin/env python3
"""Faults the filter admits: a saturated gyro, a rogue second IMU, an autopilot attitude that jumps.

    python benchmarks/faults.py [--no-write]

The flights and their scoring are ``tests/fault_flights.py`` (the simulator's hover, the fault from 4 s,
scored against the simulator's truth until 12 s); seeds 0-3 each. Per fault: the RMS error before it, the
largest and RMS error while it lasts, the mean reported uncertainty then, the seconds from its end until the
error stays under 5 deg, and the readings counted as faulty. Writes the table into benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "benchmarks")]

from broad import RESULTS, model_revision, write_section  # noqa: E402
from fault_flights import FAULTS, saturation_in_turn  # noqa: E402

FLIGHTS = {**FAULTS, "saturation_in_turn_without_gnss": lambda seed: saturation_in_turn(seed, gnss=False)}
COUNTERS = {"saturation": "gyro_saturated", "rogue_imu": "imu_disagree", "attitude_jump": "attitude_gated_jump",
            "saturation_in_turn": "gyro_saturated", "saturation_in_turn_without_gnss": "gyro_saturated"}
SEEDS = (0, 1, 2, 3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-write", action="store_true", help="do not update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    lines = [
        "| fault | error before | error while it lasts: max / RMS | reported uncertainty then (before) | recovered to < 5 deg after | "
        "error above twice the reported uncertainty after it | counted |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, flight in FLIGHTS.items():
        runs = [flight(seed=seed) for seed in SEEDS]
        s = [r.summary() for r in runs]
        rng = lambda key, fmt="{:.1f}": "–".join(fmt.format(f(v[key] for v in s)) for f in (min, max))  # noqa: E731
        counted = [r.counters.get(COUNTERS[name], 0) for r in runs]
        lines.append(f"| {runs[0].name} ({runs[0].end_s - runs[0].start_s:.0f} s) | {rng('error_before_deg')}° | "
                     f"{rng('error_during_max_deg')}° / {rng('error_during_rms_deg')}° | {rng('uncertainty_during_deg')}° "
                     f"({rng('uncertainty_before_deg')}°) | {rng('recovery_s')} s | {rng('overconfident_after_s')} s | "
                     f"{min(counted)}–{max(counted)} `{COUNTERS[name]}` |")
        print(lines[-1], flush=True)
    lines += ["", f"Seeds {', '.join(map(str, SEEDS))} (ranges over them); model at git {model_revision()}. "
                  "Before these faults were handled (git 14a9397, seed 0, the same flights): a saturated gyro left the estimate "
                  "176° off reporting 7°; a rogue IMU 64° off reporting 6°, not recovered by the end; a jumping attitude source "
                  "was followed, 30° off reporting 6°. In a sustained banked turn (the same saturation at 12 s of the programme, "
                  "scored to 25 s) the accelerometer alone re-converges to its tilt, which in a turn is the bank's (phase 1: 18° off "
                  "while reporting 4°, 15.6 s to recover); with the GNSS velocity the estimate recovers within about 4 s. After the fault "
                  "the strapdown frame is broken and the gravity update restarts from raw accelerometer readings (its fast start), "
                  "which in the turn point 11-20° off; the published tilt now widens by the excess norm of their mean at once, and "
                  "keeps it while the first GNSS-aided readings pull the estimate back only by their gain (fuser/model/unaided.py): "
                  "error above twice the reported uncertainty 2.2-2.6 s before (git ce89f91). On seeds 2 and 3 the raw readings "
                  "point 11-20° off with a norm within 1 % of g, within the 3 % tolerance of a norm not learnt; read against the "
                  "sensor's own norm, learnt over the flight (0.5 % tolerance), they show, and no tick is overconfident. The raw "
                  "readings now take the GNSS acceleration out (fuser/model/gravity.py): recovery 2.0, 2.2, 0.0 and 5.1 s on seeds "
                  "0-3 (3.6-4.2 s before)."]
    if not args.no_write:
        write_section(RESULTS, "faults", [f"## Faults the filter admits ({time.strftime('%Y-%m-%d')})", "",
                                          "Simulated hover, fault from 4 s, scored against the simulator's truth "
                                          "(`python benchmarks/faults.py`; flights in `tests/fault_flights.py`).", "", *lines])
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
