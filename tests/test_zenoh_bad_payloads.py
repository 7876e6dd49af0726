"""Anyone on the network can put on ``bingham_fuser/<vehicle>/attitude``: a payload that is not an estimate is
counted and said, never printed and never the end of ``listen`` or of a subscriber.

Found trying it: one put of ``b"not json"`` on the key ended ``bingham-fuser listen`` with "internal error:
JSONDecodeError", and a ``subscribe`` callback raised in zenoh's thread on every such put. Each payload below is
refused by :meth:`fuser.codec.Estimate.from_json` with the reason the test names (written here, not taken from
the code), and through a real zenoh session ``listen`` prints only the estimates."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from fuser import publish
from fuser.codec import Estimate, MalformedPayload
from fuser.publish import ZenohPublisher, listen, open_session, subscribe, zenoh_config
from local_net import free_port, wait_for

GOOD = Estimate(1_000_000_000, (1.0, 0.0, 0.0, 0.0), ((1.0, 0.0, 0.0, 0.0),) * 4, (0.0, -100.0, -100.0, -200.0), 2.5,
                (0.0, 1.0, 2.0), {"ticks": 1}, 999_000_000, False)


def _with(**changes) -> bytes:
    d = GOOD.to_dict() | changes
    return json.dumps({k: v for k, v in d.items() if v is not _GONE}).encode()


_GONE = object()

BAD = {
    b"not json": "not JSON",
    b"\xff\xfe{}": "not JSON",
    b"[" * 100_000: "not JSON",  # deeper than any parser's recursion
    b"[1, 2]": "not a JSON object",
    b"null": "not a JSON object",
    _with(q_wxyz=_GONE): "no q_wxyz",
    _with(t_ns=1.5): "t_ns: expected an integer",
    _with(t_ns=2**64): "t_ns: expected an integer",
    _with(t_ns=True): "t_ns: expected an integer",
    _with(q_wxyz=[1.0, 0.0, 0.0]): "q_wxyz: expected 4 finite numbers",
    _with(q_wxyz=[math.nan, 0.0, 0.0, 0.0]): "q_wxyz: expected 4 finite numbers",  # json.dumps writes NaN
    _with(q_wxyz=["1", 0, 0, 0]): "q_wxyz: expected 4 finite numbers",
    _with(M=[[1.0, 0.0, 0.0, 0.0]] * 3): "M: expected 4 rows of 4 finite numbers",
    _with(M=[[1.0, 0.0, 0.0]] * 4): "M: expected 4 rows of 4 finite numbers",
    _with(Z=[0.0, -1.0, -2.0, math.inf]): "Z: expected 4 finite numbers",
    _with(uncertainty_deg=-1.0): "uncertainty_deg: expected a finite number >= 0",
    _with(uncertainty_deg="3"): "uncertainty_deg: expected a finite number >= 0",
    _with(euler_deg={"roll": 0}): "euler_deg: expected 3 finite numbers",
    _with(counters={"ticks": "many"}): "counters: expected an object of integers",
    _with(counters=[1]): "counters: expected an object of integers",
    _with(sensor_t_ns="now"): "sensor_t_ns: expected an integer or null",
    _with(predicted=1): "predicted: expected true or false",
}


@pytest.mark.parametrize("payload", list(BAD), ids=[f"{i}-{r}" for i, r in enumerate(BAD.values())])
def test_each_payload_that_is_not_an_estimate_says_why(payload: bytes) -> None:
    with pytest.raises(MalformedPayload) as refused:
        Estimate.from_json(payload)
    assert str(refused.value) == BAD[payload]


def test_an_estimate_and_one_without_its_optional_fields_are_read() -> None:
    assert Estimate.from_json(GOOD.to_json()) == GOOD
    assert Estimate.from_json(GOOD.to_json()).to_json() == GOOD.to_json()  # the numbers as they were: same bytes
    bare = Estimate.from_json(_with(counters=_GONE, sensor_t_ns=_GONE, predicted=_GONE))
    assert (bare.counters, bare.sensor_t_ns, bare.predicted) == ({}, None, False)


JSON = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
                    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=5), inner, max_size=5),
                    max_leaves=20)


@given(st.one_of(st.binary(max_size=64), JSON.map(lambda v: json.dumps(v).encode()),
                 st.dictionaries(st.sampled_from(sorted(GOOD.to_dict())), JSON, max_size=9).map(
                     lambda d: json.dumps(GOOD.to_dict() | d).encode())))
def test_any_payload_is_an_estimate_or_refused_with_a_reason(payload: bytes) -> None:
    try:
        est = Estimate.from_json(payload)
    except MalformedPayload as exc:
        assert str(exc)
    else:
        assert est.to_json()  # what was read can be published again (finite numbers only)


class Stranger:
    """Someone else on the network, putting anything on ``bingham_fuser/evil/<leaf>``."""

    def __init__(self, endpoint: str) -> None:
        self._session = open_session(zenoh_config(listen=[endpoint]))
        # congestion control BLOCK: every put arrives (the default DROP lost the puts right after the 100-kB one)
        self._publishers = {leaf: self._session.declare_publisher(f"bingham_fuser/evil/{leaf}", congestion_control=zenoh.CongestionControl.BLOCK)
                            for leaf in ("attitude", "status")}

    def put(self, leaf: str, payload: bytes, timeout: float = 10.0) -> None:
        """Once a subscriber matches the key (a put before that reaches nobody), waiting ``timeout`` seconds at most."""
        wait_for(lambda: self._publishers[leaf].matching_status.matching, timeout, f"a subscriber to {leaf}")
        self._publishers[leaf].put(payload)

    def close(self) -> None:
        self._session.close()


@pytest.fixture
def endpoints():
    """A publisher of estimates, and a stranger putting anything on the same key, each on its own endpoint."""
    good, bad = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    pub = ZenohPublisher(zenoh_config(listen=[good]), "v1")
    stranger = Stranger(bad)
    yield pub, stranger, [good, bad]
    stranger.close()
    pub.close()


def test_listen_prints_the_estimates_and_counts_the_rest(endpoints) -> None:
    """The stranger's own estimate comes after its garbage (one publisher's puts arrive in order): by then all of
    it has been counted."""
    _, stranger, connect = endpoints
    out, err = io.StringIO(), io.StringIO()
    listener = threading.Thread(target=listen, args=(zenoh_config(connect=connect), "*"), kwargs={"count": 1, "out": out, "err": err})
    listener.start()
    stranger.put("attitude", next(iter(BAD)))
    wait_for(lambda: "further ones are counted" in err.getvalue(), timeout=20)  # said while nothing valid arrives
    for payload in list(BAD)[1:]:
        stranger.put("attitude", payload)
    stranger.put("attitude", GOOD.to_json())
    listener.join(20)
    assert not listener.is_alive()
    assert out.getvalue().splitlines() == [f"evil: {publish.format_estimate(GOOD)}"]
    said = err.getvalue().splitlines()
    assert said[0] == "listen: ignored a payload on bingham_fuser/*/attitude that is not an estimate (not JSON); further ones are counted"
    counts = {reason: list(BAD.values()).count(reason) for reason in BAD.values()}
    assert said[1] == f"listen: ignored {len(BAD)} payloads that are not estimates (" + ", ".join(
        f"{reason}: {n}" for reason, n in sorted(counts.items())) + ")"
    assert len(said) == 2


def test_a_subscriber_gets_only_estimates_and_counts_the_rest(endpoints) -> None:
    _, stranger, connect = endpoints
    got: list[Estimate] = []
    statuses: list[dict] = []
    with subscribe(zenoh_config(connect=connect), "*", got.append, statuses.append) as sub:
        for payload in BAD:
            stranger.put("attitude", payload)
        stranger.put("attitude", GOOD.to_json())
        stranger.put("status", b"[]")
        wait_for(lambda: bool(got) and sub.ignored["status: not a JSON object"] == 1, timeout=20,
                 what=f"the estimate and the status (so far {len(got)} estimates, ignored {sub.ignored})")
    assert got == [GOOD] and statuses == []
    assert sum(sub.ignored.values()) == len(BAD) + 1
    assert sub.ignored["attitude: not JSON"] == 3


def test_listen_drops_and_counts_when_printing_falls_behind(endpoints, monkeypatch: pytest.MonkeyPatch) -> None:
    """A terminal slower than the estimates: at most ``MAX_WAITING`` wait, the rest are dropped and counted."""
    pub, _, connect = endpoints
    monkeypatch.setattr(publish, "MAX_WAITING", 2)
    writing, release = threading.Event(), threading.Event()

    class Slow(io.StringIO):
        def write(self, text: str) -> int:
            writing.set()
            release.wait(30)  # the first line blocks until the test has published the rest
            return super().write(text)

    out, err = Slow(), io.StringIO()
    listener = threading.Thread(target=listen, args=(zenoh_config(connect=connect), "v1"), kwargs={"count": 3, "out": out, "err": err})
    listener.start()
    wait_for(lambda: pub.publish_estimate(GOOD) or writing.is_set(), what="a line being printed")
    for _ in range(10):
        pub.publish_estimate(GOOD)
        time.sleep(0.01)
    time.sleep(0.5)
    release.set()
    listener.join(10)
    assert not listener.is_alive()
    assert len(out.getvalue().splitlines()) == 3  # the one being printed, and the two that waited
    assert "dropped " in err.getvalue(), err.getvalue()
    assert int(err.getvalue().split("dropped ")[1].split()[0]) >= 1


def test_the_example_subscriber_skips_what_is_not_an_estimate(endpoints) -> None:
    _, stranger, connect = endpoints
    example = Path(__file__).resolve().parent.parent / "examples" / "subscribe.py"
    args = [sys.executable, str(example), "--vehicle", "*", "--count", "2"] + [a for c in connect for a in ("--connect", c)]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "subscribed"
        unreadable = [payload for payload, reason in BAD.items() if reason in ("not JSON", "not a JSON object")]
        for payload in unreadable:  # the example reads only the fields it prints: these it cannot read at all
            stranger.put("attitude", payload)
        for _ in range(2):
            stranger.put("attitude", GOOD.to_json())
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert [line.split("  ", 1)[0] for line in out.splitlines()] == ["bingham_fuser/evil/attitude"] * 2
    said = err.splitlines()
    assert len(said) == len(unreadable) == 5, said
    assert all(line.startswith("skipped a payload on bingham_fuser/evil/attitude that is not an estimate") for line in said), said


def test_listen_into_a_reader_that_stops_ends_quietly(endpoints) -> None:
    """``listen | head -2`` ended "bingham-fuser: Broken pipe", exit 1 (a pipeline under ``set -o pipefail`` failed):
    a reader that stops is the end, as ``--count``'s."""
    _, stranger, connect = endpoints
    proc = subprocess.Popen([sys.executable, "-m", "fuser.cli", "listen", "--zenoh-connect", connect[1]], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parent.parent)
    stranger.put("attitude", GOOD.to_json(), timeout=120)  # once the listener is subscribed: a new interpreter, slow under load
    assert proc.stdout.readline().startswith("evil: ")
    proc.stdout.close()  # the reader stops
    deadline = time.monotonic() + 20
    while proc.poll() is None and time.monotonic() < deadline:
        stranger.put("attitude", GOOD.to_json())
        time.sleep(0.05)
    assert proc.wait(5) == 0
    err = proc.stderr.read()
    assert "Broken pipe" not in err and "Traceback" not in err and "Exception ignored" not in err, err
