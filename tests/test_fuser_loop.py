"""The fixed-rate loop: tick grid, buffering, lateness, gaps, clocks, determinism."""

import numpy as np

from drivers.samples import ImuSample, SourceId
from fuser.config import ExtrapolationSettings, FuserConfig
from fuser.loop import FusionLoop

A = SourceId("mavlink", 1, 1, 0)
B = SourceId("dronecan", 10, 0, 0)
LEVEL = (0.0, 0.0, -9.80665)
FIXED = FuserConfig(rate_hz=100.0, latency_ms=0.0).replace(latency={"adaptive": False})
"""The loop with a fixed wait of zero: a tick runs as soon as the clock reaches it."""


def imu(t_ns, src=A, gyro=(0.0, 0.0, 0.0)):
    return ImuSample(t_ns, gyro, LEVEL, (0.21, 0.0, 0.43), src)


def test_ticks_on_a_grid_and_each_sample_in_exactly_one_tick():
    # stamped at the tick itself (by default an estimate is stamped where fuser.model.extrapolation carries it)
    loop = FusionLoop(FIXED.replace(rate_hz=100.0, extrapolation=ExtrapolationSettings(to="tick")))
    estimates = []
    for k in range(1, 401):  # 1 s of 400 Hz, received 1 ms after sending
        t = 5_000_000_000 + k * 2_500_000
        estimates += loop.advance(t + 1_000_000)
        loop.push(imu(t), t + 1_000_000)
    estimates += loop.flush()
    t_ticks = np.array([e.t_ns for e in estimates])
    assert np.all(np.diff(t_ticks) == 10_000_000) and np.all(t_ticks % 10_000_000 == 0)
    assert loop.counters["samples"] == 400 and loop.counters["late"] == 0
    # placements run from 5.0035 s to 6.001 s: the grid points 5.01 .. 6.01 cover them, once each
    assert len(estimates) == 101 and loop.counters["ticks"] == 101
    assert t_ticks[0] == 5_010_000_000 and t_ticks[-1] == 6_010_000_000


def test_late_samples_are_counted_and_dropped():
    loop = FusionLoop(FIXED)
    loop.push(imu(1_000_000_000), 1_000_000_000)
    loop.advance(1_100_000_000)
    loop.push(imu(1_050_000_000), 1_050_000_000)  # placed before a tick that already ran
    assert loop.counters["late"] == 1


def test_out_of_order_samples_within_a_tick_are_sorted():
    loop_a = FusionLoop(FIXED)
    loop_b = FusionLoop(FIXED)
    samples = [imu(1_000_000_000 + k * 2_500_000, gyro=(0.1 * k, 0.0, 0.0)) for k in range(8)]
    for s in samples:
        loop_a.push(s, 1_000_000_000 + (s.t_ns - 1_000_000_000))
    for s in samples[:1] + samples[:0:-1]:  # same placements; after the first, arrival order reversed
        loop_b.push(s, s.t_ns)
    ea, eb = loop_a.flush(), loop_b.flush()
    assert [e.to_dict() for e in ea] == [e.to_dict() for e in eb]


def test_ticks_continue_through_a_gap_and_uncertainty_grows():
    loop = FusionLoop(FIXED)
    for k in range(1, 101):
        t = 1_000_000_000 + k * 10_000_000
        loop.push(imu(t), t)
        loop.advance(t)
    before = loop.advance(2_010_000_000)
    during = loop.advance(4_000_000_000)  # 2 s without any sample: ticks still run
    assert len(during) >= 190
    assert during[-1].uncertainty_deg > before[-1].uncertainty_deg + 5
    assert during[-1].counters["no_gyro"] >= 190


def test_replay_catch_up_skips_long_gaps_and_counts_them():
    loop = FusionLoop(FIXED, max_catch_up_ticks=100)
    loop.push(imu(1_000_000_000), 1_000_000_000)
    out = loop.advance(1_000_000_000 + 3600 * 10**9)  # an hour later
    assert len(out) <= 102 and loop.counters["ticks_skipped"] > 359_000


def test_sources_with_different_clocks_share_the_timeline():
    """Each stream is placed at its own time plus its smallest latency: two IMUs whose
    clocks differ by hours land in the same ticks."""
    loop = FusionLoop(FIXED)
    for k in range(1, 41):
        rx = 50_000_000_000 + k * 2_500_000
        loop.push(imu(k * 2_500_000, A), rx + 300_000)
        loop.push(imu(7_200_000_000_000 + k * 2_500_000, B), rx + 700_000)
    est = loop.flush()
    assert loop.counters["late"] == 0 and len(est) == 11
    assert est[-1].sensor_t_ns is not None and abs(est[-1].sensor_t_ns - (est[-1].t_ns - 50_000_000_000 - 300_000)) < 1


def test_same_input_gives_same_output():
    def run():
        loop = FusionLoop(FuserConfig())
        rng = np.random.default_rng(3)
        out = []
        for k in range(1, 801):
            t = k * 2_500_000
            out += loop.advance(t)
            loop.push(ImuSample(t, tuple(rng.normal(0, 0.1, 3)), tuple(np.array(LEVEL) + rng.normal(0, 0.2, 3)), tuple(rng.normal([0.21, 0, 0.43], 0.01)), A), t)
        return [e.to_dict() for e in out + loop.flush()]

    assert run() == run()


# -- the wait for samples in flight ([fuser.latency]) ----------------------------------------------------------

def _feed(loop, events):
    """``(t_ns, receive_ns, sample)`` in arrival order through the loop, as Pipeline.feed does; the waits in force."""
    waits, out = [], []
    for _, rx, sample in events:
        out += loop.advance(rx)
        loop.push(sample, rx)
        waits.append(loop.latency_ns)
    return np.array(waits), out + loop.flush()


def _stream(n, period_ns, latency_ns, src=A, t0=10_000_000_000):
    """``n`` IMU samples every ``period_ns``, each received ``latency_ns[k]`` after its time, in arrival order."""
    events = [(t0 + k * period_ns, t0 + k * period_ns + int(latency_ns[k]), imu(t0 + k * period_ns, src)) for k in range(n)]
    return sorted(events, key=lambda e: e[1])


def test_a_wired_link_keeps_the_floor_after_its_first_samples():
    """400 Hz with 0.5 ms + exponential 0.3 ms latency (a companion computer's wire): once the stream has shown its
    lateness the wait comes down to the 5 ms floor, by at most half a tick period per tick (5 ms each 10 ms: the
    held-back ticks run at twice the rate); until then (its first samples) the cap."""
    rng = np.random.default_rng(1)
    n = 4000
    loop = FusionLoop(FuserConfig())
    waits, _ = _feed(loop, _stream(n, 2_500_000, 500_000 + rng.exponential(300_000, n)))
    assert waits[0] == 250_000_000  # the cap, before any lateness is known
    assert np.all(waits[:400] == 250_000_000) and np.all(np.diff(waits) >= -5_000_000)
    assert np.all(waits[700:] == 5_000_000)  # from the measurement a second in: the floor (the wire's jitter is under 3 ms)
    assert loop.counters["late"] == 0


def test_a_radio_link_waits_for_its_jitter_and_loses_under_one_percent():
    """A SiK-like radio: 25 ms plus gamma(2, 12 ms) latency, delivered in 20 ms air frames, first in first out,
    10 Hz. A fixed 5 ms wait drops most samples; the adaptive wait covers the jitter's 99.5th percentile."""
    rng = np.random.default_rng(2)
    n, period = 3000, 100_000_000
    t = 10_000_000_000 + np.arange(n) * period
    arrival = np.ceil((t + 25e6 + rng.gamma(2.0, 12e6, n)) / 20e6) * 20e6 + rng.uniform(0, 2e6, n)
    arrival = np.maximum.accumulate(arrival).astype(np.int64)
    events = [(int(a), int(r), imu(int(a))) for a, r in zip(t, arrival)]
    # a 20 Hz loop: twice the link's rate is enough to test the wait, and 300 s of flight stay quick
    fixed = FusionLoop(FuserConfig(rate_hz=20.0).replace(latency={"adaptive": False}))
    _feed(fixed, events)
    assert fixed.counters["late"] > 0.5 * n
    loop = FusionLoop(FuserConfig(rate_hz=20.0))
    waits, _ = _feed(loop, events)
    assert loop.counters["late"] <= 0.01 * n
    jitter = (arrival - t) - (arrival - t).min()
    settled = waits[n // 2:]
    assert np.percentile(jitter, 95) <= settled.min() and settled.max() <= jitter.max() + 1  # 30-s windows: about their p99.5
    assert settled.max() < 250_000_000


def test_a_stall_at_start_up_loses_nothing_and_the_wait_recovers():
    """The receiver reads nothing for the first 0.3 s of a 400 Hz stream (start-up under load), then everything
    queued at once, then every sample 1 ms after its time: none is dropped (the first offset is the stall's, and
    every faster sample after it lowers it), and once the stall has left the window the wait is the floor again."""
    n = 20_000  # 50 s
    t0 = 10_000_000_000
    t = t0 + np.arange(n) * 2_500_000
    latency = np.maximum(1_000_000, t0 + 300_000_000 - t)
    loop = FusionLoop(FuserConfig())
    waits, estimates = _feed(loop, _stream(n, 2_500_000, latency, t0=t0))
    assert loop.counters["late"] == 0 and loop.counters["samples"] == n
    assert waits[-1] == 5_000_000
    assert len(estimates) == loop.counters["ticks"]


def test_a_link_that_slows_down_raises_the_wait_at_once():
    loop = FusionLoop(FuserConfig())
    events = _stream(2000, 2_500_000, np.full(2000, 1_000_000))
    waits, _ = _feed(loop, events)
    assert waits[-1] == 5_000_000
    t = events[-1][0] + 2_500_000
    loop.advance(t + 41_000_000)
    loop.push(imu(t), t + 41_000_000)  # 40 ms later than the stream's least latency
    assert loop.timeline.wait_ns == 40_000_000 and loop.next_due_ns == loop._next_tick + 40_000_000


def test_a_fixed_wait_longer_than_the_cap_wins():
    loop = FusionLoop(FuserConfig(latency_ms=400.0))
    assert loop.latency_ns == 400_000_000
