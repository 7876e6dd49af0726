"""Scores, plots and a summary of a fused log: estimates against the reference attitude, named as what it is.

Estimates carry ``sensor_t_ns``, the tick time on the vehicle's clock, so they are compared with
the reference (``/truth/pose``: a simulator's truth, an imported benchmark's motion capture, a PX4
log's EKF2 estimate; else the autopilot's own attitude inputs) at exactly that time.

The reference is named from the MCAP metadata ``reference`` key where the log has one (written by
``bingham-fuser import``, carried over by replay), else inferred from the log's ``source``:

| where | named |
| --- | --- |
| ``reference`` starts with "EKF2" / "EKF3" | ``EKF2`` / ``EKF3`` (another estimator, not ground truth) |
| ``reference`` mentions motion capture, or the source is BROAD | ``motion capture`` |
| the source is ``bingham-fuser sim`` | ``simulator truth`` |
| the source is a PX4 ULog / an ArduPilot DataFlash log | ``EKF2`` / ``EKF3`` |
| no ``/truth/pose``: the autopilot's ATTITUDE inputs | ``autopilot attitude`` |

:func:`write_report` writes ``attitude.png`` (roll, pitch, yaw against the reference, the
estimate's 2-sigma band), ``error.png`` (total, tilt and heading error with their RMS on the
plot; the actual error against the reported uncertainty), ``counters.png`` (every counter of the
loop and the model over time) and ``summary.md`` beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from numpy.typing import NDArray

from drivers.euler import euler_from_quaternion
from drivers.samples import AttitudeSample, Quat
from fuser.codec import Estimate, decode_sample, loads
from fuser.errors import FuserError, UsageError, os_reason
from fuser.evaluate import REGIONS, AttitudeErrors, attitude_errors
from fuser.frames import orientation_covariance_ned
from fuser.record import LogContents, LogStream, _quat_wxyz, read_log

__all__ = ["Reference", "StreamedScore", "errors_of_log", "reference_of", "score_log", "stream_score", "write_report"]

CONVERGENCE_S = 5.0
"""Scores leave out the first seconds, while the filter converges from a uniform start."""
BAND_SIGMA = 2.0
"""Width of the uncertainty band on the attitude plot, in sigmas (about 95 %)."""
_ALWAYS = ("samples", "ticks")
"""Counters every tick increments: in the summary, not on the counter plot."""


@dataclass(frozen=True)
class Reference:
    """What the estimates are compared with."""

    name: str
    """Short name for plots: ``simulator truth``, ``motion capture``, ``EKF2``, ``EKF3``, ``autopilot attitude``."""
    detail: str
    """Where the name comes from (the metadata's words, or the inference)."""
    ground_truth: bool
    """True for a simulator's truth or motion capture; False for another estimator."""


def _from_words(text: str) -> tuple[str, bool] | None:
    t = text.lower()
    for ekf in ("ekf2", "ekf3"):
        if t.startswith(ekf) or f" {ekf}" in t:
            return ekf.upper(), False
    if "motion capture" in t or "broad" in t or "mocap" in t:
        return "motion capture", True
    if "sim" in t.split() or "simulat" in t or "bingham-fuser sim" in t:
        return "simulator truth", True
    if "px4" in t or "ulog" in t:
        return "EKF2", False
    if "ardupilot" in t or "dataflash" in t:
        return "EKF3", False
    return None


def reference_of(contents: LogContents) -> Reference:
    """Name the reference of a log (see the module docstring)."""
    return _reference(contents.metadata, any(m.topic == "/truth/pose" for m in contents.raw))


def _reference(metadata: dict[str, dict[str, str]], has_truth: bool) -> Reference:
    """Name the reference of a log with this metadata, with or without ``/truth/pose``."""
    meta = metadata.get("bingham_fuser", {})
    if not has_truth:
        return Reference("autopilot attitude", "the autopilot's own attitude messages (no /truth/pose)", False)
    if "reference" in meta:
        named = _from_words(meta["reference"])
        if named is not None:
            return Reference(named[0], f"metadata reference: {meta['reference']}", named[1])
    source = meta.get("source", "")
    named = _from_words(source)
    if named is not None:
        return Reference(named[0], f"inferred from the log's source: {source}", named[1])
    return Reference("truth", "/truth/pose of unknown origin", True)


def _unscored(path: str | Path, contents: LogContents) -> str:
    """Why a log cannot be scored, in the user's terms."""
    estimates = timed = 0
    for e in contents.estimates():
        estimates += 1
        timed += e.sensor_t_ns is not None
    return _why_unscored(path, estimates, timed)


def _why_unscored(path: str | Path, estimates: int, timed: int) -> str:
    """Why a log with ``estimates`` estimates, ``timed`` of them with an IMU time, cannot be scored."""
    if not estimates:
        return (f"{path} holds no estimates (an imported or input-only log): fuse it first, "
                f"'bingham-fuser replay {path} -o fused.mcap', then report fused.mcap")
    if not timed:
        return (f"none of the {estimates:,} estimates in {path} has an IMU time: no IMU sample reached the filter (the log "
                "it was fused from has no IMU messages?), so there is no time to line them up with a reference by")
    return f"{path} has no reference attitude to score against (no truth, and fewer than two autopilot attitude samples)"


def errors_of_log(path: str | Path, contents: LogContents | None = None) -> tuple[str, AttitudeErrors] | None:
    """(``truth`` or ``autopilot attitude``: where the reference came from, errors) for a log's
    estimates, or None if it has no reference or no estimates."""
    contents = read_log(path) if contents is None else contents
    estimates = [e for e in contents.estimates() if e.sensor_t_ns is not None]
    if not estimates:
        return None
    truth = contents.truth()
    if truth:
        kind, ref = "truth", truth
    else:
        ref = [(s.t_ns, s.q_wxyz) for s, _ in contents.inputs() if isinstance(s, AttitudeSample)]
        kind = "autopilot attitude"
        if len(ref) < 2:
            return None
    ref_t = np.array([t for t, _ in ref], dtype=np.int64)
    ref_q = np.array([q for _, q in ref], dtype=float)
    t = np.array([e.sensor_t_ns for e in estimates], dtype=np.int64)
    q = np.array([e.q_wxyz for e in estimates], dtype=float)
    unc = np.array([e.uncertainty_deg for e in estimates], dtype=float)
    bingham = np.array([e.M for e in estimates], dtype=float), np.array([e.Z for e in estimates], dtype=float)
    return kind, attitude_errors(t, q, unc, ref_t, ref_q, bingham)


def _circular(contents: LogContents, ref: Reference) -> str | None:
    """A note when the reference is the autopilot's estimate and the fuser took that estimate as a measurement (``auto``
    with a slow or no IMU, or ``--attitude-sigma``): the score is then largely agreement with its own input."""
    if ref.ground_truth:
        return None
    taken = sum(isinstance(s, AttitudeSample) for s, _ in contents.inputs())
    return _circular_note(ref, taken, next((e.counters for e in reversed(contents.estimates())), {}))


def _circular_note(ref: Reference, taken: int, counters: dict[str, int]) -> str | None:
    """:func:`_circular`'s note, from the attitude samples the log holds and the last estimate's ``counters``."""
    if ref.ground_truth:
        return None
    fused = taken - sum(v for k, v in counters.items() if k == "attitude_unused" or k.startswith("attitude_gated"))
    if fused <= 0:
        return None
    return (f"note: the fuser fused {fused:,} of the autopilot's {taken:,} attitude samples, and {ref.name} is that "
            "autopilot's estimate: the comparison is circular (it shows how closely the fuser followed its input); "
            "replay with --no-attitude to score the fuser's own estimate")


def _window(err: AttitudeErrors, since_s: float) -> float:
    """``since_s``, or 0 when the flight is too short to leave out the convergence."""
    return _span_window(int(err.t_ns[0]), int(err.t_ns[-1]), since_s)


def _span_window(first_ns: int, last_ns: int, since_s: float) -> float:
    """:func:`_window` for scored estimates from ``first_ns`` to ``last_ns`` (what :func:`stream_score` keeps)."""
    return since_s if (last_ns - first_ns) * 1e-9 > since_s else 0.0


def _score_lines(ref: Reference, rms: dict[str, float], since_s: float, coverage: dict[float, float]) -> list[str]:
    """The score's lines: the RMS errors (:meth:`AttitudeErrors.rms`) after ``since_s``, and how often the estimates'
    credible regions held the reference (:meth:`AttitudeErrors.coverage`; its line left out when it is empty)."""
    window = f"after the first {since_s:g} s" if since_s > 0 else "over the whole flight, convergence included"
    lines = [
        f"error against {ref.name} {window} (RMS, degrees):",
        f"  total {rms['total']:.2f}   tilt {rms['tilt']:.2f}   heading {rms['heading']:.2f}   "
        f"reported uncertainty {rms['uncertainty']:.2f}",
    ]
    if coverage:
        regions = _regions()
        meaning = f"honest: about {regions}" if ref.ground_truth else "another estimator's error is in it too: agreement, not calibration"
        lines.append(f"  {ref.name} inside the {regions} % credible regions: "
                     f"{' / '.join(f'{100 * coverage[a]:.0f}' for a in REGIONS)} % of the time ({meaning})")
    return lines


def _regions() -> str:
    """``50 / 90 / 95``: :data:`~fuser.evaluate.REGIONS` in percent."""
    return " / ".join(f"{100 * a:g}" for a in REGIONS)


def score_log(path: str | Path, since_s: float = CONVERGENCE_S) -> list[str]:
    """Lines of a summary table: RMS errors after the first ``since_s`` seconds (convergence).

    The log is read as a stream (:func:`stream_score`): the memory taken does not grow with its estimates."""
    score = stream_score(path, since_s)
    if score.unscored is not None:
        return [f"{path}: {score.unscored}"]
    if score.matched == 0:
        return [f"{path}: no estimate within the time span of the {score.reference.name} to score against"]
    return _score_lines(score.reference, score.rms, score.since_s, score.coverage) + ([score.circular] if score.circular else [])


@dataclass(frozen=True)
class StreamedScore:
    """What :func:`score_log` prints, as :func:`errors_of_log` and :meth:`AttitudeErrors.rms` after :func:`_window`
    give it, computed in one pass over the estimates (:func:`stream_score`)."""

    reference: Reference
    unscored: str | None
    """Why the log has no score (:func:`_why_unscored`), or None."""
    matched: int
    """Estimates inside the reference's time span: those scored."""
    since_s: float
    """The convergence left out: the ``since_s`` asked for, or 0 for a flight too short to leave it out."""
    rms: dict[str, float]
    """RMS ``total``, ``tilt``, ``heading`` and ``uncertainty``, degrees (empty when nothing was scored)."""
    circular: str | None = None
    """:func:`_circular`'s note, or None."""
    coverage: dict[float, float] = field(default_factory=dict)
    """As :meth:`AttitudeErrors.coverage` gives it over the same estimates as ``rms`` (empty when nothing was scored)."""


ESTIMATES_PER_BLOCK = 65_536
"""Estimates :func:`stream_score` compares with the reference at a time (14 MB of arrays, Binghams included)."""


class _SquareSums:
    """Sums of the squared errors of :class:`AttitudeErrors` blocks, over every estimate and over those at least
    ``since_s`` after the first: both RMS are at hand when the end of the log tells which one is wanted."""

    NAMES = ("total", "tilt", "heading", "uncertainty")

    def __init__(self, since_s: float) -> None:
        self.since_ns = since_s * 1e9
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.count = {"all": 0, "since": 0}
        self.sums = {window: dict.fromkeys(self.NAMES, 0.0) for window in self.count}
        self.inside = {window: dict.fromkeys(REGIONS, 0) for window in self.count}
        """Estimates whose credible region of each mass held the reference."""

    def add(self, err: AttitudeErrors) -> None:
        """Add one block's errors (its estimates in log-time order, after the blocks added before)."""
        if err.t_ns.size == 0:
            return
        if self.first_ns is None:
            self.first_ns = int(err.t_ns[0])
        self.last_ns = int(err.t_ns[-1])
        since = (err.t_ns - self.first_ns) >= self.since_ns
        self.count["all"] += err.t_ns.size
        self.count["since"] += int(np.count_nonzero(since))
        for name, values in zip(self.NAMES, (err.total_deg, err.tilt_deg, err.heading_deg, err.uncertainty_deg)):
            squares = values**2
            self.sums["all"][name] += float(np.sum(squares))
            self.sums["since"][name] += float(np.sum(squares[since]))
        assert err.level is not None  # stream_score passes every estimate's Bingham
        for a in REGIONS:
            held = err.level <= a
            self.inside["all"][a] += int(np.count_nonzero(held))
            self.inside["since"][a] += int(np.count_nonzero(held[since]))

    def rms(self, window: str) -> dict[str, float]:
        """The RMS of each error over ``window`` (``all`` or ``since``)."""
        n = self.count[window]
        return {name: math.sqrt(total / n) if n else math.nan for name, total in self.sums[window].items()}

    def coverage(self, window: str) -> dict[float, float]:
        """The fraction of the estimates over ``window`` whose credible region of each mass held the reference."""
        n = self.count[window]
        return {a: held / n for a, held in self.inside[window].items()} if n else {}


def stream_score(path: str | Path, since_s: float = CONVERGENCE_S) -> StreamedScore:
    """The score :func:`score_log` prints, reading the log as a stream (:class:`~fuser.record.LogStream`): the
    reference (times and quaternions, a few per second) is kept, the estimates are compared with it
    :data:`ESTIMATES_PER_BLOCK` at a time, and only their squared errors are summed."""
    log = LogStream(path)
    topics = log.overview.topics
    ref = _reference(log.overview.metadata, topics["/truth/pose"] > 0)
    reference = _reference_samples(log)
    sums = _SquareSums(since_s)
    estimates = _Estimates()
    for t, q, unc, M, Z in estimates.blocks(log):
        if reference is not None:
            sums.add(attitude_errors(t, q, unc, *reference, bingham=(M, Z)))
    if not estimates.timed or reference is None:
        return StreamedScore(ref, _why_unscored(path, estimates.count, estimates.timed), 0, since_s, {})
    if sums.first_ns is None or sums.last_ns is None:
        return StreamedScore(ref, None, 0, since_s, {})
    window = _span_window(sums.first_ns, sums.last_ns, since_s)
    circular = _circular_note(ref, topics["/input/attitude"], estimates.last_counters)
    scored = "since" if window > 0 else "all"
    return StreamedScore(ref, None, sums.count["all"], window, sums.rms(scored), circular, sums.coverage(scored))


def _reference_samples(log: LogStream) -> tuple[NDArray, NDArray] | None:
    """(times, quaternions) of what :func:`errors_of_log` compares with: ``/truth/pose`` at its publish time, else
    the autopilot's attitude inputs (None if fewer than two)."""
    times: list[int] = []
    quats: list[Quat] = []
    if log.overview.topics["/truth/pose"]:
        for m in log.messages(["/truth/pose"]):
            times.append(m.publish_time)
            quats.append(_quat_wxyz(loads(m.data)))
    else:
        for m in log.messages(["/input/attitude"]):
            sample, _ = decode_sample(m.topic, loads(m.data))
            if isinstance(sample, AttitudeSample):
                times.append(sample.t_ns)
                quats.append(sample.q_wxyz)
        if len(times) < 2:
            return None
    return np.array(times, dtype=np.int64), np.array(quats, dtype=float)


class _Estimates:
    """The ``/estimate`` messages of a log read in blocks (:meth:`blocks`), and what is counted on the way."""

    def __init__(self) -> None:
        self.count = 0
        self.timed = 0
        """Estimates with an IMU time (``sensor_t_ns``)."""
        self.last_counters: dict[str, int] = {}
        """The counters of the last estimate in log-time order."""

    def blocks(self, log: LogStream) -> Iterator[tuple[NDArray, ...]]:
        """The estimates with an IMU time, in log-time order, as (IMU times, quaternions, uncertainties, Bingham
        ``M``, ``Z``) arrays of at most :data:`ESTIMATES_PER_BLOCK`."""
        block = _Block(ESTIMATES_PER_BLOCK)
        for m in log.messages(["/estimate"]):
            d = loads(m.data)
            self.count += 1
            self.last_counters = d.get("counters", {})
            if d.get("sensor_t_ns") is None:
                continue
            self.timed += 1
            if block.add(d):
                yield block.arrays()
                block = _Block(ESTIMATES_PER_BLOCK)
        if block.n:
            yield block.arrays()


class _Block:
    """Up to ``size`` estimates' fields in arrays, filled row by row: the JSON's lists are not kept (a block of
    their Python floats took four times the arrays' memory)."""

    def __init__(self, size: int) -> None:
        self.n = 0
        self.t = np.empty(size, dtype=np.int64)
        self.q, self.unc, self.M, self.Z = np.empty((size, 4)), np.empty(size), np.empty((size, 4, 4)), np.empty((size, 4))

    def add(self, d: dict) -> bool:
        """Add one estimate's payload; True when the block is full."""
        i = self.n
        self.t[i], self.q[i], self.unc[i], self.M[i], self.Z[i] = d["sensor_t_ns"], d["q_wxyz"], d["uncertainty_deg"], d["M"], d["Z"]
        self.n += 1
        return self.n == self.t.size

    def arrays(self) -> tuple[NDArray, ...]:
        """(IMU times, quaternions, uncertainties, ``M``, ``Z``) of the estimates added."""
        return tuple(a[: self.n] for a in (self.t, self.q, self.unc, self.M, self.Z))


def _euler_deg(q: NDArray) -> NDArray:
    """Roll, pitch, yaw (ZYX) in degrees, one row per quaternion."""
    return np.degrees(np.array([euler_from_quaternion(tuple(row)) for row in q]))


def _euler_sigma_deg(estimates: list[Estimate], euler_deg: NDArray) -> NDArray:
    """One-sigma roll, pitch, yaw of each estimate: the Bingham's world-frame covariance mapped to
    ZYX Euler angles. A small world-frame rotation ``delta`` changes them by ``E^-1 delta`` with
    ``E = [Rz Ry e_x, Rz e_y, e_z]`` (columns for roll, pitch, yaw); near pitch +-90 deg, where
    roll and yaw are undefined, their sigmas are left out (NaN)."""
    out = np.full((len(estimates), 3), np.nan)
    for i, (est, (_, pitch, yaw)) in enumerate(zip(estimates, np.radians(euler_deg), strict=True)):
        if abs(math.cos(pitch)) < 1e-3:
            continue
        cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
        E = np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])
        Einv = np.linalg.inv(E)
        cov = Einv @ orientation_covariance_ned(est.M, est.Z, est.q_wxyz) @ Einv.T
        out[i] = np.degrees(np.sqrt(np.maximum(np.diag(cov), 0.0)))
    return out


def _matched_estimates(contents: LogContents, err: AttitudeErrors) -> list[Estimate]:
    """The estimates ``err`` compares, in its order (those inside the reference's time span)."""
    by_time = {e.sensor_t_ns: e for e in contents.estimates() if e.sensor_t_ns is not None}
    return [by_time[int(t)] for t in err.t_ns]


def _counters(contents: LogContents) -> tuple[NDArray, dict[str, NDArray], dict[str, int]]:
    """Tick times (s from the first), each rejection counter over time, and the final counts."""
    estimates = contents.estimates()
    t = np.array([e.t_ns for e in estimates], dtype=np.int64)
    names = sorted({k for e in estimates for k in e.counters} - set(_ALWAYS))
    series = {n: np.array([e.counters.get(n, 0) for e in estimates]) for n in names}
    final = dict(sorted(estimates[-1].counters.items())) if estimates else {}
    return (t - t[0]) * 1e-9 if len(t) else t * 1.0, series, final


def write_report(path: str | Path, out_dir: Path, since_s: float = CONVERGENCE_S) -> list[str]:
    """Write ``attitude.png``, ``error.png``, ``counters.png`` and ``summary.md`` into ``out_dir``;
    return the summary lines printed by the CLI."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    contents = read_log(path)
    result = errors_of_log(path, contents)
    if result is None:
        raise UsageError(f"report: {_unscored(path, contents)}")
    err = result[1]
    ref = reference_of(contents)
    if err.t_ns.size == 0:
        raise UsageError(f"report: no estimate of {path} lies within the time span of its {ref.name}")
    since_s = _window(err, since_s)
    rms = err.rms(since_s)
    out_dir.mkdir(parents=True, exist_ok=True)
    title = f"{Path(path).name}: bingham-fuser against {ref.name}"
    t = (err.t_ns - err.t_ns[0]) * 1e-9

    # attitude: roll, pitch, yaw against the reference, with the estimate's 2-sigma band
    est_euler = _euler_deg(err.q_est)
    ref_euler = _euler_deg(err.q_ref)
    est_euler[:, 2] = np.degrees(np.unwrap(np.radians(est_euler[:, 2])))
    ref_euler[:, 2] = est_euler[:, 2] + (ref_euler[:, 2] - est_euler[:, 2] + 180.0) % 360.0 - 180.0
    sigma = _euler_sigma_deg(_matched_estimates(contents, err), _euler_deg(err.q_est))
    fig, ax = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    for i, label in enumerate(("roll", "pitch", "yaw")):
        ax[i].fill_between(t, est_euler[:, i] - BAND_SIGMA * sigma[:, i], est_euler[:, i] + BAND_SIGMA * sigma[:, i],
                           color="tab:blue", alpha=0.2, lw=0, label=f"estimate ± {BAND_SIGMA:g} sigma")
        ax[i].plot(t, est_euler[:, i], color="tab:blue", lw=1.0, label="bingham-fuser")
        ax[i].plot(t, ref_euler[:, i], color="tab:orange", lw=1.0, ls="--", label=ref.name)
        ax[i].set_ylabel(f"{label} [deg]")
        ax[i].grid(alpha=0.3)
    ax[0].legend(loc="upper right", fontsize=8, ncol=3)
    ax[-1].set_xlabel("time [s]")
    fig.suptitle(f"{title}: attitude (ZYX Euler)")
    fig.tight_layout()
    _write(out_dir / "attitude.png", lambda file: fig.savefig(file, dpi=100))
    plt.close(fig)

    # error: per component with its RMS, and the actual error against the reported uncertainty
    fig, ax = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for values, label in ((err.total_deg, "total"), (err.tilt_deg, "tilt"), (err.heading_deg, "heading")):
        ax[0].plot(t, values, lw=0.8, label=f"{label}: RMS {rms[label]:.2f}°")
    if since_s > 0:
        for a in ax:
            a.axvspan(0, since_s, color="0.85", lw=0)
    window = f"RMS after the first {since_s:g} s (grey: convergence, left out)" if since_s > 0 else "RMS over the whole flight"
    ax[0].set_title(window, fontsize=9)
    ax[0].set_ylabel(f"error vs {ref.name} [deg]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].fill_between(t, 0, err.uncertainty_deg, color="tab:green", alpha=0.3, lw=0,
                       label=f"reported RMS uncertainty (RMS {rms['uncertainty']:.2f}°)")
    ax[1].plot(t, err.total_deg, lw=0.8, color="tab:blue", label=f"actual total error (RMS {rms['total']:.2f}°)")
    if err.level is not None:  # where the reported uncertainty was overconfident: the reference outside the 90 % region
        outside = err.level > 0.9
        ax[1].plot(t[outside], err.total_deg[outside], ls="none", marker=".", ms=2.5, color="tab:red",
                   label=f"{ref.name} outside the 90 % credible region ({100 * np.mean(outside):.0f} % of the estimates plotted)")
    ax[1].set_ylabel("deg")
    ax[1].set_xlabel("time [s]")
    ax[1].legend(loc="upper right", fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
        a.set_ylim(bottom=0)
    fig.suptitle(f"{title}: error")
    fig.tight_layout()
    _write(out_dir / "error.png", lambda file: fig.savefig(file, dpi=100))
    plt.close(fig)

    # counters: every rejection and gap counter over time (cumulative)
    tick_s, series, final = _counters(contents)
    fig, ax = plt.subplots(figsize=(11, 4))
    for name, values in series.items():
        ax.step(tick_s, values, where="post", lw=1.0, label=f"{name}: {int(values[-1])}")
    if series:
        ax.legend(loc="upper left", fontsize=8)
    else:
        ax.text(0.5, 0.5, "no sample rejected, no gap", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlim(0, max(float(tick_s[-1]), 1.0) if len(tick_s) else 1.0)
    ax.set_xlabel("time [s]")
    ax.set_yscale("symlog", linthresh=1.0)  # a handful of gaps stays visible beside thousands of rest ticks
    ax.set_ylim(bottom=0)
    ax.set_ylabel("count (cumulative, log scale above 1)")
    ax.set_title(f"{title}: counters ({final.get('ticks', 0)} ticks, {final.get('samples', 0)} samples)", fontsize=10)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _write(out_dir / "counters.png", lambda file: fig.savefig(file, dpi=100))
    plt.close(fig)

    circular = _circular(contents, ref)
    coverage = err.coverage(since_s)
    lines = _score_lines(ref, rms, since_s, coverage) + ([circular] if circular else [])
    summary = _summary(Path(path).name, ref, err, rms, coverage, since_s, final) + (
        f"\n**Note:** {circular.removeprefix('note: ')}.\n" if circular else "")
    _write(out_dir / "summary.md", lambda file: file.write_text(summary))
    return lines + [f"report: {out_dir / 'summary.md'}, attitude.png, error.png, counters.png"]


def _write(file: Path, write: Callable[[Path], object]) -> None:
    """``write(file)``; a file the disk cannot hold (full, read-only) is removed and named in one error (a full disk left
    a truncated attitude.png and said only "No space left on device")."""
    try:
        write(file)
    except OSError as e:
        file.unlink(missing_ok=True)
        raise FuserError(f"report: cannot write {file}: {os_reason(e)}") from e


def _summary(log_name: str, ref: Reference, err: AttitudeErrors, rms: dict[str, float], coverage: dict[float, float],
             since_s: float, counters: dict[str, int]) -> str:
    window = f"after the first {since_s:g} s (convergence left out)" if since_s > 0 else "over the whole flight (too short to leave out the convergence)"
    kind = "ground truth" if ref.ground_truth else "another estimator, not ground truth: the figures are agreement, not accuracy"
    duration = (err.t_ns[-1] - err.t_ns[0]) * 1e-9
    rows = "\n".join(f"| {name} | {rms[name]:.2f} |" for name in ("total", "tilt", "heading", "uncertainty"))
    inside = "\n".join(f"| {100 * a:g} % | {100 * f:.1f} % |" for a, f in coverage.items())
    counts = "\n".join(f"| {k} | {v} |" for k, v in counters.items())
    return f"""# bingham-fuser report: {log_name}

Reference: **{ref.name}** ({kind}); {ref.detail}.

{len(err.t_ns)} estimates over {duration:.1f} s compared with the reference at the same instant (slerp);
RMS {window}, degrees ("uncertainty" is the RMS of the reported uncertainty):

| error | RMS [deg] |
| --- | --- |
{rows}

How often the {ref.name} lay inside the estimate's credible region, over the same estimates: an honest uncertainty
holds it about as often as the region's mass; more often, it is wider than it needs to be; less often, overconfident.

| credible region | {ref.name} inside |
| --- | --- |
{inside}

Counters at the end of the log:

| counter | count |
| --- | --- |
{counts}

Plots: [attitude.png](attitude.png) (roll, pitch, yaw against {ref.name}, the estimate's {BAND_SIGMA:g}-sigma band),
[error.png](error.png) (errors with their RMS; actual error against the reported uncertainty),
[counters.png](counters.png) (rejections and gaps over time).
"""
