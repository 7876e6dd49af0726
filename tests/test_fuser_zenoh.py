"""zenoh: estimates reach a subscriber in another process intact, across subscriber restarts and failures."""

from __future__ import annotations

import io
import json
import logging
import queue
import random
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from fuser.codec import Estimate
from fuser.publish import ZenohPublisher, format_estimate, listen, subscribe, zenoh_config
from local_net import free_port, wait_for

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "subscribe.py"


def estimates(n: int, seed: int) -> list[Estimate]:
    rng = random.Random(seed)
    out = []
    for i in range(n):
        m = tuple(tuple(rng.uniform(-1, 1) for _ in range(4)) for _ in range(4))
        q = tuple(rng.uniform(-1, 1) for _ in range(4))
        z = (0.0, -rng.uniform(1, 1e5), -1e5, -2e5)
        e = (rng.uniform(-180, 180), rng.uniform(-90, 90), rng.uniform(-180, 180))
        out.append(Estimate(10_000_000 * (seed * 1000 + i), q, m, z, rng.random(), e, {"ticks": i, "late": seed}))
    return out


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def publisher(endpoint: str):
    pub = ZenohPublisher(zenoh_config(listen=[endpoint]), "v1")
    yield pub
    pub.close()


def start_example(endpoint: str, count: int) -> subprocess.Popen[str]:
    """The example subscriber in another process, printing raw JSON; returns once it has subscribed."""
    proc = subprocess.Popen(
        [sys.executable, str(EXAMPLE), "--connect", endpoint, "--vehicle", "v1", "--raw", "--count", str(count)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "subscribed"
    return proc


def send_to(proc: subprocess.Popen[str], pub: ZenohPublisher, sent: list[Estimate]) -> list[Estimate]:
    """Publish ``sent`` once ``proc`` matches, each once the previous one has been printed; return what it printed.

    One in flight at a time, as a live loop's one estimate per tick is: the publisher's puts use congestion
    control DROP (fuser/publish.py), so a burst could lose its last ones to a full queue (50 put as fast as Python
    can: one run in six; 1 ms apart on a cold cache, both cores compiling: the subscriber printed 1 of 30 and
    waited)."""
    wait_for(lambda: pub.has_subscribers)
    assert proc.stdout is not None
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True)  # type: ignore[union-attr]
    reader.start()
    printed = []
    for est in sent:
        pub.publish_estimate(est)
        printed.append(lines.get(timeout=60))  # a liveness limit: a fresh clone's first run shares both cores with numba
    assert proc.wait(timeout=60) == 0
    return [Estimate.from_dict(json.loads(line)) for line in printed]


def test_estimates_reach_another_process_intact_across_restarts(publisher: ZenohPublisher, endpoint: str) -> None:
    first = estimates(50, seed=1)
    assert send_to(start_example(endpoint, 50), publisher, first) == first

    # The subscriber is gone: publishing goes on without error.
    wait_for(lambda: not publisher.has_subscribers)
    for est in estimates(20, seed=2):
        publisher.publish_estimate(est)

    # A killed subscriber does not hurt the publisher either.
    victim = start_example(endpoint, 1000)
    wait_for(lambda: publisher.has_subscribers)
    victim.kill()
    victim.communicate()
    for est in estimates(20, seed=3):
        publisher.publish_estimate(est)
    # the next subscriber must be the one matched: the victim's match can outlive it for a moment, and estimates
    # published then would go to nobody (the test failed so on a loaded machine)
    wait_for(lambda: not publisher.has_subscribers)

    second = estimates(30, seed=4)
    assert send_to(start_example(endpoint, 30), publisher, second) == second
    assert publisher.errors == 0 and publisher.published == 50 + 20 + 20 + 30


def test_subscribe_and_listen_in_process(publisher: ZenohPublisher, endpoint: str) -> None:
    got: list[Estimate] = []
    statuses: list[dict] = []
    sent = estimates(5, seed=5)
    status = {"ticks": 5, "recorder_alive": False}
    with subscribe(zenoh_config(connect=[endpoint]), "*", got.append, statuses.append):
        wait_for(lambda: publisher.has_subscribers)
        for est in sent:
            publisher.publish_estimate(est)
        wait_for(lambda: len(got) == 5)
        # the status subscriber is declared after the attitude one and may match a moment later:
        # publish until one status has arrived
        wait_for(lambda: publisher.publish_status(status) or bool(statuses))
    assert got == sent
    assert statuses and all(s == status for s in statuses)

    # listen() prints one line per estimate; publish until it has printed 3 (its session connects when it can).
    stream = estimates(1000, seed=6)
    lines = _listened(publisher, endpoint, "v1", 3, stream)
    first = [format_estimate(e) for e in stream].index(lines[0])
    assert lines == [format_estimate(e) for e in stream[first : first + 3]]
    roll, _, yaw = stream[first].euler_deg
    assert f"roll={roll:8.3f}" in lines[0] and f"yaw={yaw:8.3f}" in lines[0]
    assert f"+/-{stream[first].uncertainty_deg:.3f} deg" in lines[0]

    # listening to every vehicle (listen's default), each line says whose it is
    stream = estimates(1000, seed=7)
    lines = _listened(publisher, endpoint, "*", 2, stream)
    first = [f"v1: {format_estimate(e)}" for e in stream].index(lines[0])
    assert lines == [f"v1: {format_estimate(e)}" for e in stream[first : first + 2]]


def _listened(publisher: ZenohPublisher, endpoint: str, vehicle: str, count: int, stream: list[Estimate]) -> list[str]:
    """What listen() printed for ``vehicle`` while ``stream`` was published, one estimate per 10 ms, until it had
    printed ``count`` lines."""
    out = io.StringIO()
    listener = threading.Thread(target=listen, args=(zenoh_config(connect=[endpoint]), vehicle), kwargs={"count": count, "out": out})
    listener.start()
    for est in stream:
        if not listener.is_alive():
            break
        publisher.publish_estimate(est)
        time.sleep(0.01)
    listener.join(1)
    assert not listener.is_alive()
    lines = out.getvalue().splitlines()
    assert len(lines) == count, lines
    return lines


def test_publisher_that_cannot_open_counts_and_says_so_once(endpoint: str, caplog: pytest.LogCaptureFixture) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", int(endpoint.rsplit(":", 1)[1])))
        busy.listen()
        with caplog.at_level(logging.ERROR, logger="fuser.publish"):
            pub = ZenohPublisher(zenoh_config(listen=[endpoint]), "v1")
            for est in estimates(3, seed=6):
                pub.publish_estimate(est)
            pub.publish_status({})
            pub.close()
    assert pub.errors == 1 + 4 and pub.published == 0 and not pub.has_subscribers
    assert "cannot open the zenoh session" in (pub.error or "")
    assert len(caplog.records) == 1


def test_config_defaults_listen_on_loopback_only_when_not_connecting() -> None:
    default = json.loads(zenoh_config().get_json("listen/endpoints"))
    assert default == ["tcp/127.0.0.1:7447"]
    assert json.loads(zenoh_config(connect=["tcp/10.0.0.1:7447"]).get_json("listen/endpoints")) == []
    assert json.loads(zenoh_config().get_json("scouting/multicast/enabled")) is False


def test_each_command_names_its_vehicle_unless_one_is_configured(tmp_path: Path) -> None:
    """A live vehicle's estimates are not published as the simulator's (``run`` used ``sim`` too), and ``listen``
    hears every vehicle unless told which (``*``: :func:`subscribe` above hears ``v1`` through it)."""
    from fuser import cli

    def vehicle(argv: list[str]) -> str:
        args, _ = cli._parser().parse_known_args(argv)
        return cli._config(args).vehicle

    assert vehicle(["sim"]) == "sim"
    assert vehicle(["run", "--mavlink", "udpin:127.0.0.1:14550"]) == "vehicle"
    assert vehicle(["listen"]) == "*"
    assert vehicle(["run", "--mavlink", "udpin:127.0.0.1:14550", "--vehicle", "hexa1"]) == "hexa1"
    (tmp_path / "fleet.toml").write_text('[fuser]\nvehicle = "hexa2"\n')
    assert vehicle(["listen", "--config", str(tmp_path / "fleet.toml")]) == "hexa2"


def test_a_vehicle_name_is_one_chunk_of_the_zenoh_keys():
    """What the keys ``bingham_fuser/<vehicle>/...`` can hold (zenoh's own parser decides, and no wildcard is
    published); ``*`` is a listener's every vehicle."""
    from fuser.publish import check_vehicle

    for name in ("sim", "vehicle", "drone 1", "uav-7_b", "ä"):
        check_vehicle(name)
    check_vehicle("*", listening=True)
    for name in ("", "a/b", "*", "**", "$x", "x#y", "x?y"):
        with pytest.raises(ValueError, match="is not a name for the zenoh keys"):
            check_vehicle(name)
